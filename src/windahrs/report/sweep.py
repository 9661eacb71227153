"""Files of ``windahrs sweep-report``: summary.md, PNG figures and report.html from a
sweep's Parquet rows.

Rows are grouped by scenario family (vehicle, turbulence, duration, altitude): one table
per family (estimator × wind speed: runs, mean and spread of the total, tilt and per-axis
RMSE over seeds, convergence, NEES, PCRB ratio) and one figure per family and metric
(RMSE against wind speed per estimator with the spread over seeds).
"""

from __future__ import annotations

import math
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from windahrs.report.figures import versus_wind_png
from windahrs.report.html import Image, Section, Table, render_html, write_html, write_text

__all__ = ["write_sweep_report"]

FAMILY = ("vehicle", "turbulence", "duration", "altitude")


def _family_name(key: tuple[Any, ...]) -> str:
    vehicle, turbulence, duration, altitude = key
    alt = "" if altitude is None or (isinstance(altitude, float) and math.isnan(altitude)) else f", {altitude:g} m"
    return f"{vehicle}, {duration:g} s, turbulence {'on' if turbulence else 'off'}{alt}"


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in text).strip("_").lower()


def _nanmean(v: list[float]) -> float | None:
    a = np.asarray(v, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(a.mean()) if a.size else None


def _nanmedian(v: list[float]) -> float | None:
    a = np.asarray(v, dtype=np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None


def _spread(v: list[float]) -> str | None:
    a = np.asarray(v, dtype=np.float64)
    a = a[np.isfinite(a)]
    if not a.size:
        return None
    return f"{a.mean():.3f} ± {a.std(ddof=1) if a.size > 1 else 0.0:.3f}"


def write_sweep_report(rows: dict[str, list[Any]], out: Path, *, title: str = "windahrs sweep") -> list[Path]:
    """Write summary.md, one PNG per family and metric, and report.html into ``out``.

    rows: column -> values (the sweep's Parquet columns,
    :data:`windahrs.experiments.sweep.COLUMNS`), e.g. ``read_results(path).to_pydict()``.
    """
    n = len(rows["run_id"])
    if n == 0:
        raise ValueError("results: expected at least one row, found none")
    out.mkdir(parents=True, exist_ok=True)
    fams: dict[tuple[Any, ...], list[int]] = defaultdict(list)
    for i in range(n):
        fams[tuple(rows[k][i] for k in FAMILY)].append(i)
    written: list[Path] = []
    sections: list[Section] = []
    md = [f"# {title}", ""]
    flights = len({(rows["seed"][i], rows["wind"][i], *(rows[k][i] for k in FAMILY)) for i in range(n)})
    intro = (
        f"{n} rows (run × estimator) from {flights} simulated flights. RMSE in degrees from sample "
        "50 against the simulation truth, mean ± standard deviation over seeds; convergence: median time after "
        "which the total error stays under 5 deg; NEES: attitude and gyro bias (6-dim), second half, mean over "
        "seeds (expected 6 when consistent); RMSE/sqrt(PCRB): body axes x/y/z, second half, only for the "
        "estimators `windahrs reproduce` bounds (ekf7, mekf, usque, ins-wind) and only for sweeps run with "
        "pcrb = true; '–' where not applicable. Rows whose estimator raised are counted under 'failed', runs "
        "whose estimator warned (a reset, a sensor mostly gated out; the Parquet column 'warnings' has the "
        "messages) under 'with warnings'."
    )
    md += [intro, ""]
    sections.append(Section("What was run", paragraphs=[intro]))
    for key in sorted(fams, key=lambda k: tuple(str(x) for x in k)):
        idx = fams[key]
        name = _family_name(key)
        estimators = list(dict.fromkeys(rows["estimator"][i] for i in sorted(idx, key=lambda j: rows["estimator"][j])))
        winds = sorted({rows["wind"][i] for i in idx})
        cells: dict[tuple[str, float], list[int]] = defaultdict(list)
        for i in idx:
            cells[rows["estimator"][i], rows["wind"][i]].append(i)
        table_rows = []
        for est in estimators:
            for w in winds:
                ii = cells.get((est, w), [])
                if not ii:
                    continue
                ok = [i for i in ii if not rows["error"][i]]

                def col(c: str, ok: list[int] = ok) -> list[float]:
                    return [rows[c][i] for i in ok]

                ratio = [_nanmean(col(f"pcrb_ratio_{a}")) for a in "xyz"]
                table_rows.append([
                    est, w, len(ok), len(ii) - len(ok), sum(bool(rows["warnings"][i]) for i in ok),
                    _spread(col("rmse_total_deg")), _spread(col("rmse_tilt_deg")),
                    " / ".join(f"{v:.3f}" for v in (_nanmean(col(f"rmse_{a}_deg")) or math.nan
                                                    for a in ("roll", "pitch", "yaw"))) if ok else None,
                    _nanmedian(col("convergence_s")), _nanmean(col("nees_mean")),
                    None if any(r is None for r in ratio) else " / ".join(f"{r:.2f}" for r in ratio),
                    _nanmean(col("seconds")),
                ])
        table = Table(
            ["estimator", "wind [m/s]", "runs", "failed", "with warnings", "total RMSE [deg]", "tilt RMSE [deg]",
             "RMSE r/p/y [deg], mean", "convergence [s], median", "NEES, mean", "RMSE/sqrt(PCRB) x/y/z",
             "run time [s], mean"],
            table_rows, caption=name,
        )
        images: list[Image] = []
        names: list[str] = []
        for metric, label in (("rmse_total_deg", "total RMSE [deg]"), ("rmse_tilt_deg", "tilt RMSE [deg]")):
            values: dict[str, np.ndarray] = {}
            for est in estimators:
                per = [[rows[metric][i] for i in cells.get((est, w), []) if not rows["error"][i]] for w in winds]
                width = max((len(p) for p in per), default=0)
                if width == 0:
                    continue
                values[est] = np.array([p + [math.nan] * (width - len(p)) for p in per], dtype=np.float64)
            if not values:
                continue
            fig_title = f"{label.split(' [')[0]} against wind: {name}"
            png = versus_wind_png(winds, values, label, fig_title)
            fname = f"{_slug(name)}_{metric}.png"
            (out / fname).write_bytes(png)
            written.append(out / fname)
            images.append(Image(png, fig_title, alt=fig_title))
            names.append(fname)
        sections.append(Section(name, tables=[table], images=images))
        md += [f"## {name}", "", table.to_markdown(), ""]
        md += [f"![{img.caption}]({f})\n" for img, f in zip(images, names, strict=True)]
    write_text(out / "summary.md", "\n".join(md))
    written.append(out / "summary.md")
    write_html(out / "report.html", render_html(title, sections))
    written.append(out / "report.html")
    return written
