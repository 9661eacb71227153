"""Files of ``windahrs reproduce``: results.json, results.md, PNG figures, report.html.

One source of numbers: every table is built once from the reproduction's case rows and
rendered both to Markdown and to HTML; results.json holds the same rows.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np

from windahrs.experiments.reproduce import CLAIMS, ReproductionResult, claims
from windahrs.report.figures import error_vs_bound_png, error_vs_sample_png
from windahrs.report.html import Image, Section, Table, render_html, write_html, write_text
from windahrs.store import write_bytes

__all__ = ["write_reproduction"]


def _fmt3(v: Sequence[float] | None) -> str | None:
    return None if v is None else " / ".join(f"{x:.2f}" for x in v)


def results_table(res: ReproductionResult, wind: float) -> Table:
    rows = []
    for c in res.cases:
        if c["wind"] != wind:
            continue
        rows.append(
            [
                c["filter"],
                c["wind_model"],
                _fmt3(c["rmse_from50_deg"]),
                _fmt3(c["rmse_steady_deg"]),
                c["convergence_samples"],
                _fmt3(c["pcrb_ratio"]),
                c["nees_in_band"],
            ]
        )
    return Table(
        [
            "filter",
            "wind",
            "RMSE from sample 50, r/p/y [deg]",
            "RMSE 2nd half, r/p/y [deg]",
            "convergence [samples]",
            "RMSE/sqrt(PCRB), r/p/y",
            "NEES in band",
        ],
        rows,
        caption=f"Wind {wind:g} m/s, {res.meta['runs']} runs of {res.meta['duration_s']:g} s",
    )


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def consistency_table(res: ReproductionResult) -> Table | None:
    """The physically tuned filters' NEES (SPEC 6.3) on the reproduction's runs and, when
    the reproduction ran a NEES check on more flights, on all of them and per block."""
    n, m = res.meta["runs"], res.meta.get("nees_runs", res.meta["runs"])
    rows: list[list[Any]] = []
    for c in res.cases:
        if c.get("nees_mean") is None:
            continue
        row = [c["filter"], f"{c['wind']:g}", c["nees_mean"], _pct(c["nees_in_band"])]
        chk = c.get("nees_check")
        if m > n:
            if chk is None:
                row += [None, None, None]
            else:
                row += [chk["nees_mean"], f"{_pct(chk['in_band'])} in [{chk['band'][0]:.2f}, {chk['band'][1]:.2f}]",
                        f"{chk['blocks_passing']} of {len(chk['blocks_in_band'])}"]
        rows.append(row)
    if not rows:
        return None
    cols = ["filter", "wind [m/s]", f"NEES, {n} runs", f"steps in the {n}-run band"]
    caption = f"Consistency: NEES of attitude and gyro bias (6 dof), second half, {n} runs"
    if m > n:
        cols += [f"NEES, {m} runs", f"steps in the {m}-run band", f"blocks of {n} runs with >= 90 % of steps in band"]
        caption = f"Consistency: NEES of attitude and gyro bias (6 dof), second half, {n} and {m} runs"
    return Table(cols, rows, caption=caption)


def claims_table(res: ReproductionResult) -> Table:
    rows: list[list[Any]] = []
    highlight: dict[tuple[int, int], Literal["good", "bad"]] = {}
    for i, c in enumerate(claims(res)):
        rows.append([c["claim"], "holds" if c["holds"] else "does not hold", c["numbers"]])
        highlight[(i, 1)] = "good" if c["holds"] else "bad"
    cols = ["the paper claims", "verdict", "our numbers"]
    return Table(cols, rows, caption="The paper's claims", highlight=highlight)


def _series(res: ReproductionResult, labels: dict[str, str]) -> dict[str, np.ndarray]:
    return {name: res.errors[key] for key, name in labels.items() if key in res.errors}


def _figures(res: ReproductionResult) -> list[tuple[str, bytes, str]]:
    figs: list[tuple[str, bytes, str]] = []
    for w, fig in ((5.0, "fig4"), (8.0, "fig5")):
        s = _series(
            res,
            {
                "0 m/s | paper": "no wind",
                f"{w:g} m/s | paper": "considering wind (oracle)",
                f"{w:g} m/s | paper:wind=mean": "considering wind (mean only)",
                f"{w:g} m/s | paper-nowind": "not considering wind",
            },
        )
        if s:
            title = f"Paper Fig. {fig[-1]}: attitude error, wind {w:g} m/s"
            figs.append((f"{fig}.png", error_vs_sample_png(s, title, unit="deg"), title))
    s = _series(res, {"5 m/s | ekf": "EKF", "5 m/s | ukf": "UKF", "5 m/s | paper": "proposed (oracle wind)"})
    if s:
        title = "Paper Fig. 6: EKF, UKF and the proposed filter, wind 5 m/s"
        figs.append(("fig6.png", error_vs_sample_png(s, title, unit="deg"), title))
    for w in sorted({c["wind"] for c in res.cases}):
        s = _series(
            res,
            {f"{w:g} m/s | {f}": f for f in ("paper", "mekf", "ekf7", "usque", "mekf-air", "ins-wind")},
        )
        if s:
            title = f"Modern estimators against the paper's, wind {w:g} m/s"
            figs.append((f"estimators_{w:g}.png", error_vs_sample_png(s, title, unit="deg"), title))
        for model in ("ins", "gravity"):
            bkey = f"{w:g} m/s | {model}"
            if bkey not in res.bounds:
                continue
            users = [c["filter"] for c in res.cases if c["wind"] == w and c.get("bound") == model]
            rm = {f: np.sqrt(np.mean(res.errors[f"{w:g} m/s | {f}"] ** 2, axis=0)) for f in users}
            if rm:
                title = f"RMSE against the PCRB ({model} model), wind {w:g} m/s"
                figs.append((f"pcrb_{model}_{w:g}.png", error_vs_bound_png(rm, res.bounds[bkey], title), title))
    return figs


def write_reproduction(res: ReproductionResult, out: Path) -> list[Path]:
    """Write results.json, results.md, the figures and report.html into ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    claim_rows = claims(res)
    payload = {"cases": [{k: v for k, v in c.items() if k != "bound"} for c in res.cases], "claims": claim_rows,
               "meta": res.meta}
    write_text(out / "results.json", json.dumps(payload, indent=1))
    written.append(out / "results.json")
    winds = sorted({c["wind"] for c in res.cases})
    tables = [claims_table(res)] + [results_table(res, w) for w in winds]
    consistency = consistency_table(res)
    if consistency is not None:
        tables.append(consistency)
    intro = (
        f"The paper's section 4 experiment by the protocol of SPEC 7.3: {res.meta['runs']} seeded runs of "
        f"{res.meta['duration_s']:g} s per wind speed (200 Hz IMU, magnetometer 50 Hz, GNSS 10 Hz, vanes and "
        "pitot 50 Hz, Dryden turbulence at 20 m), every estimator on the same flights. Claimed errors "
        f"considering wind: {CLAIMS[5.0]} deg at 5 m/s and {CLAIMS[8.0]} deg at 8 m/s. Convergence: samples until "
        f"the median total error stays under {res.meta['convergence_deg']:g} deg. RMSE/sqrt(PCRB) and NEES "
        "(6-dim, attitude and gyro bias, fraction of second-half steps inside the 95 % chi-square band) only for "
        "the physically tuned filters, whose parameters equal the simulated sensors' datasheet noise."
    )
    if res.meta.get("nees_runs", res.meta["runs"]) > res.meta["runs"]:
        intro += (
            f" Their NEES is also checked on {res.meta['nees_runs']} runs (the same seed sequence continued): a "
            f"band of that many runs is narrower, and the per-block column shows how often one block of "
            f"{res.meta['runs']} runs passes the 90 % test on its own."
        )
    md = ["# Reproduction of Zheng, Wang and Pei, section 4", "", intro, ""]
    for tab in tables:
        md += [f"## {tab.caption}", "", tab.to_markdown(), ""]
    figs = _figures(res)
    for name, png, title in figs:
        write_bytes(out / name, png)
        written.append(out / name)
        md += [f"![{title}]({name})", ""]
    write_text(out / "results.md", "\n".join(md))
    written.append(out / "results.md")
    sections = [Section("What was run", paragraphs=[intro], tables=[tables[0]])]
    sections += [Section(t.caption, tables=[t]) for t in tables[1:]]
    sections.append(Section("Figures", images=[Image(png, title, alt=title) for _, png, title in figs]))
    write_html(out / "report.html", render_html("windahrs: reproduction of the paper's experiments", sections))
    written.append(out / "report.html")
    return written

