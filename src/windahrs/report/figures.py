"""Report figures as PNG bytes.

Drawn with ``matplotlib.figure.Figure`` on a ``FigureCanvasAgg`` created per figure: no
pyplot, no backend switch, no rcParams change, so importing or calling this module never
alters matplotlib's global state (a user's interactive session is left alone). matplotlib
is imported on first use, so ``windahrs.report`` (HTML, tables) works without it.

Figures are 9 x 6 in at 100 dpi (900 x 600 px), white background, saved as 256-colour
PNG (typically 5-65 kB). Long series are reduced to at most ``MAX_POINTS`` points per
line by a min/max envelope per bucket: spikes survive, and a series of 1e6 samples plots
in well under a second.
"""

from __future__ import annotations

import io
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

__all__ = [
    "AXES",
    "MAX_POINTS",
    "error_vs_bound_png",
    "error_vs_sample_png",
    "grouped_bars_png",
    "timeseries_png",
]

F64 = NDArray[np.float64]

AXES = ("roll", "pitch", "yaw")
MAX_POINTS = 4000
FIGSIZE = (9.0, 6.0)  # in
DPI = 100
_BAND = (10.0, 90.0)  # percent, the shaded spread over runs


# ---------------------------------------------------------------------------------------
# public figures


def error_vs_sample_png(
    series: Mapping[str, ArrayLike],
    title: str,
    *,
    unit: Literal["rad", "deg"] = "rad",
    max_samples: int | None = None,
) -> bytes:
    """Attitude error against sample index, one panel per axis (roll, pitch, yaw), as in
    the paper's error-vs-number-of-samples figures.

    series: label -> errors in ``unit`` (rad or deg), shape (runs, N, 3) (N may differ between labels; NaN
    marks missing samples); for each label the median over runs is drawn as a line and
    the 10-90 % spread over runs as a shaded band. Pass absolute errors to plot error
    magnitudes. The axes are in degrees whatever ``unit`` is. max_samples: plot
    only the first max_samples samples. Returns PNG bytes.
    """
    if not series:
        raise ValueError("series: expected at least one labelled error array, found none")
    if max_samples is not None and (not isinstance(max_samples, int) or max_samples < 1):
        raise ValueError(f"max_samples: expected a positive int or None, found {max_samples!r}")
    if unit not in ("rad", "deg"):
        raise ValueError(f"unit: expected 'rad' or 'deg', found {unit!r}")
    scale = math.degrees(1.0) if unit == "rad" else 1.0
    fig, axes = _new_figure(3)
    for k, (label, values) in enumerate(series.items()):
        err = _as_float(values, f"series[{label!r}]")
        if err.ndim != 3 or err.shape[2] != 3 or err.shape[0] < 1 or err.shape[1] < 1:
            raise ValueError(f"series[{label!r}]: expected shape (runs, N, 3), found {err.shape}")
        if max_samples is not None:
            err = err[:, :max_samples]
        err = err * scale
        x = np.arange(err.shape[1], dtype=np.float64)
        lo, med, hi = _percentiles_over_runs(err, (_BAND[0], 50.0, _BAND[1]))
        color = f"C{k % 10}"
        for a, ax in enumerate(axes):
            xb, lo_b, _ = _envelope(x, lo[:, a], MAX_POINTS // 2)
            _, _, hi_b = _envelope(x, hi[:, a], MAX_POINTS // 2)
            ax.fill_between(xb, lo_b, hi_b, color=color, alpha=0.2, linewidth=0)
            xl, yl = _line(x, med[:, a], MAX_POINTS)
            ax.plot(xl, yl, color=color, linewidth=1.2, label=label)
    for a, ax in enumerate(axes):
        ax.set_ylabel(f"{AXES[a]} error [deg]")
        ax.axhline(0.0, color="0.5", linewidth=0.6, zorder=0)
    axes[-1].set_xlabel("sample index")
    _legend(fig, axes[0], title=f"median over runs, band {_BAND[0]:g}-{_BAND[1]:g} %")
    return _finish(fig, title)


def error_vs_bound_png(
    rmse_deg: Mapping[str, ArrayLike],
    bound_std_deg: ArrayLike,
    title: str,
    *,
    t: ArrayLike | None = None,
) -> bytes:
    """RMSE over runs against time for each estimator, with the posterior Cramer-Rao bound.

    rmse_deg: label -> RMSE over Monte Carlo runs in deg, shape (N, 3) (roll, pitch, yaw);
    bound_std_deg: the PCRB standard deviation in deg, shape (N, 3), drawn as a dashed
    black line; t: sample times in s, shape (N,) (default: sample index). One panel per
    axis, logarithmic y axis (non-positive values are not drawn). Returns PNG bytes.
    """
    if not rmse_deg:
        raise ValueError("rmse_deg: expected at least one labelled RMSE array, found none")
    bound = _as_float(bound_std_deg, "bound_std_deg")
    if bound.ndim != 2 or bound.shape[1] != 3 or bound.shape[0] < 1:
        raise ValueError(f"bound_std_deg: expected shape (N, 3), found {bound.shape}")
    n = bound.shape[0]
    x, xlabel = _time_axis(t, n, "t")
    fig, axes = _new_figure(3)
    for k, (label, values) in enumerate(rmse_deg.items()):
        r = _as_float(values, f"rmse_deg[{label!r}]")
        if r.shape != (n, 3):
            raise ValueError(f"rmse_deg[{label!r}]: expected shape ({n}, 3) like bound_std_deg, found {r.shape}")
        for a, ax in enumerate(axes):
            xl, yl = _line(x, _positive(r[:, a]), MAX_POINTS)
            ax.plot(xl, yl, color=f"C{k % 10}", linewidth=1.2, label=label)
    for a, ax in enumerate(axes):
        xl, yl = _line(x, _positive(bound[:, a]), MAX_POINTS)
        ax.plot(xl, yl, color="black", linestyle="--", linewidth=1.2, label="PCRB std")
        ax.set_yscale("log")
        _plain_log_labels(ax)
        ax.set_ylabel(f"{AXES[a]} RMSE [deg]")
    axes[-1].set_xlabel(xlabel)
    _legend(fig, axes[0])
    return _finish(fig, title)


def timeseries_png(
    t: ArrayLike,
    curves: Mapping[str, ArrayLike | tuple[ArrayLike, ArrayLike]],
    ylabel: str,
    title: str,
    *,
    panels: Sequence[str] | None = None,
    reference: str | None = None,
    hlines: Mapping[str, float] | None = None,
    logy: bool = False,
) -> bytes:
    """Generic time series in stacked panels (attitude vs reference, wind vs the log's
    wind, innovations or NIS per sensor, ...).

    t: time in s, shape (N,). curves: label -> values of shape (N,) or (N, k) on ``t``, or
    a tuple ``(t_own, values)`` for a curve on its own time base (e.g. a reference at
    another rate); column j goes to panel j; NaN leaves a gap. panels: one name per panel
    (the number of columns; default: unnamed, as many as the widest curve); a 1-D curve
    with several panels is an error. ylabel: the y axis label with unit, e.g. "angle [deg]".
    reference: label of the curve drawn as the reference (thin black line, on top).
    hlines: label -> y value of horizontal guide lines drawn in every panel (e.g. a
    chi-square band). logy: logarithmic y axis. Returns PNG bytes.
    """
    if not curves:
        raise ValueError("curves: expected at least one labelled curve, found none")
    if reference is not None and reference not in curves:
        raise ValueError(f"reference: expected one of the curve labels {list(curves)}, found {reference!r}")
    t0 = _as_float(t, "t")
    if t0.ndim != 1:
        raise ValueError(f"t: expected shape (N,), found {t0.shape}")
    prepared: list[tuple[str, F64, F64]] = []
    for label, value in curves.items():
        if isinstance(value, tuple):
            if len(value) != 2:
                raise ValueError(
                    f"curves[{label!r}]: expected an array or a (t, values) pair, found a tuple of {len(value)}"
                )
            tc = _as_float(value[0], f"curves[{label!r}] time")
            y = _as_float(value[1], f"curves[{label!r}]")
            if tc.ndim != 1:
                raise ValueError(f"curves[{label!r}] time: expected shape (M,), found {tc.shape}")
        else:
            tc, y = t0, _as_float(value, f"curves[{label!r}]")
        if y.ndim == 1:
            y = y[:, None]
        if y.ndim != 2 or y.shape[0] != tc.shape[0]:
            raise ValueError(
                f"curves[{label!r}]: expected shape ({tc.shape[0]},) or ({tc.shape[0]}, k) matching its "
                f"time, found {y.shape}"
            )
        prepared.append((label, tc, y))
    n_panels = len(panels) if panels is not None else max(y.shape[1] for _, _, y in prepared)
    if n_panels < 1:
        raise ValueError("panels: expected at least one panel name, found none")
    for label, _, y in prepared:
        if y.shape[1] != n_panels:
            raise ValueError(f"curves[{label!r}]: expected {n_panels} column(s), one per panel, found {y.shape[1]}")
    fig, axes = _new_figure(n_panels)
    for k, (label, tc, y) in enumerate(prepared):
        is_ref = label == reference
        # The reference on top, thin: where the estimate agrees it hides it, differences show.
        style: dict[str, Any] = (
            {"color": "black", "linewidth": 0.8, "zorder": 3}
            if is_ref
            else {"color": f"C{k % 10}", "linewidth": 1.1, "zorder": 2}
        )
        for j, ax in enumerate(axes):
            xl, yl = _line(tc, _positive(y[:, j]) if logy else y[:, j], MAX_POINTS)
            ax.plot(xl, yl, label=label, **style)
    for j, ax in enumerate(axes):
        for h, (name, value) in enumerate((hlines or {}).items()):
            ax.axhline(
                float(value),
                color="0.45",
                linestyle=":",
                linewidth=1.0,
                label=name if j == 0 else None,
                zorder=0,
                dashes=(1, 1 + h),
            )
        if logy:
            ax.set_yscale("log")
            _plain_log_labels(ax)
        ax.set_ylabel(ylabel)
        if panels is not None:
            ax.set_title(panels[j], loc="left", fontsize=9, pad=2)
    axes[-1].set_xlabel("time [s]")
    _legend(fig, axes[0])
    return _finish(fig, title)


def grouped_bars_png(
    values: Mapping[str, ArrayLike],
    groups: Sequence[str],
    ylabel: str,
    title: str,
    *,
    logy: bool = False,
) -> bytes:
    """Grouped bar chart, e.g. RMSE per estimator (one colour per label) for each axis
    (one group per entry of ``groups``). values: label -> shape (len(groups),); a NaN
    value is drawn as "n/a" instead of a bar. ylabel with unit. Returns PNG bytes."""
    if not values:
        raise ValueError("values: expected at least one labelled array, found none")
    groups = list(groups)
    if not groups:
        raise ValueError("groups: expected at least one group name, found none")
    fig, axes = _new_figure(1)
    ax = axes[0]
    width = 0.8 / len(values)
    x = np.arange(len(groups), dtype=np.float64)
    for k, (label, v) in enumerate(values.items()):
        y = _as_float(v, f"values[{label!r}]")
        if y.shape != (len(groups),):
            raise ValueError(f"values[{label!r}]: expected shape ({len(groups)},), found {y.shape}")
        pos = x - 0.4 + width * (k + 0.5)
        ok = np.isfinite(y)
        bars = ax.bar(pos[ok], y[ok], width=width * 0.95, color=f"C{k % 10}", label=label)
        ax.bar_label(bars, fmt="%.3g", fontsize=7, padding=1)
        for xp in pos[~ok]:  # a missing value is shown, not silently left out
            ax.annotate(
                "n/a",
                (xp, 0.0),
                xycoords=("data", "axes fraction"),  # at the bottom, on linear or log axes
                xytext=(0, 2),
                textcoords="offset points",
                ha="center",
                va="bottom",
                fontsize=7,
                color=f"C{k % 10}",
            )
    ax.set_xticks(x, groups)
    ax.set_xlim(-0.5, len(groups) - 0.5)  # room for every slot, drawn or "n/a"
    ax.set_ylabel(ylabel)
    if logy:
        ax.set_yscale("log")
        _plain_log_labels(ax)
    _legend(fig, ax)
    return _finish(fig, title)


# ---------------------------------------------------------------------------------------
# helpers


def spans_png(
    rows: Mapping[str, Sequence[tuple[float, float, str]]], t_range: tuple[float, float], title: str
) -> bytes:
    """Time spans in stacked panels, one per label of ``rows`` (e.g. an estimator), each span
    (t0 s, t1 s, name) a bar on its name's line (a span of one instant drawn as a thin bar);
    t_range the time axis. Returns PNG bytes."""
    if not rows:
        raise ValueError("rows: expected at least one labelled list of spans, found none")
    fig, axes = _new_figure(len(rows))
    width = max((t_range[1] - t_range[0]) / 500.0, 1e-6)  # an instant, visible
    for ax, (label, spans) in zip(axes, rows.items(), strict=True):
        names = sorted({name for _, _, name in spans})
        for i, name in enumerate(names):
            bars = [(t0, max(t1 - t0, width)) for t0, t1, n in spans if n == name]
            ax.broken_barh(bars, (i - 0.35, 0.7), color=f"C{i % 10}")
        ax.set_yticks(range(len(names)), names, fontsize=7)
        ax.set_ylim(-0.6, max(len(names), 1) - 0.4)
        ax.set_xlim(*t_range)
        ax.set_title(label, loc="left", fontsize=9, pad=2)
    axes[-1].set_xlabel("time [s]")
    return _finish(fig, title)


def _new_figure(nrows: int) -> tuple[Figure, list[Axes]]:
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError("report figures need matplotlib: pip install 'windahrs[report]'") from exc
    fig = Figure(figsize=FIGSIZE, dpi=DPI, layout="constrained", facecolor="white")
    axs = fig.subplots(nrows, 1, sharex=True, squeeze=False)
    axes = [ax for ax in axs[:, 0]]
    for ax in axes:
        ax.grid(True, linewidth=0.5, alpha=0.5)
        ax.tick_params(labelsize=8)
        ax.yaxis.label.set_fontsize(9)
        ax.xaxis.label.set_fontsize(9)
    return fig, axes


def _legend(fig: Figure, ax: Axes, *, title: str | None = None) -> None:
    """One legend for the figure, below the panels (never over the data or the title)."""
    handles, labels = ax.get_legend_handles_labels()
    if handles:
        fig.legend(
            handles,
            labels,
            loc="outside lower center",
            ncols=min(len(handles), 5),
            fontsize=8,
            title=title,
            title_fontsize=8,
            frameon=False,
        )


def _plain_log_labels(ax: Axes) -> None:
    """Log-axis ticks as plain numbers (0.3, 2) rather than 3x10^-1; minor ticks labelled
    only when the axis spans few decades (otherwise they would crowd)."""
    from matplotlib.ticker import FuncFormatter

    def major(v: float, pos: int | None = None) -> str:
        return f"{v:g}"

    def minor(v: float, pos: int | None = None) -> str:
        lo, hi = ax.get_ylim()
        if v <= 0 or lo <= 0 or hi <= lo:
            return ""
        decades = math.log10(hi / lo)
        mantissa = round(v / 10 ** math.floor(math.log10(v)))
        shown = {2, 3, 5} if decades < 1.5 else {2, 5} if decades < 2.5 else set()
        return f"{v:g}" if mantissa in shown else ""

    ax.yaxis.set_major_formatter(FuncFormatter(major))
    ax.yaxis.set_minor_formatter(FuncFormatter(minor))


def _finish(fig: Figure, title: str) -> bytes:
    """Render with Agg and encode as a 256-colour PNG: plots have few colours, and the
    palette makes files 3-4 times smaller than RGBA with no visible change. Maximum-coverage
    quantisation keeps the dominant colours (white background, line colours) exact and
    bounds the error of the rare antialiasing shades."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from PIL import Image  # Pillow is a dependency of matplotlib

    fig.suptitle(title, fontsize=11)
    canvas = FigureCanvasAgg(fig)  # attaches itself as fig.canvas; no global backend involved
    canvas.draw()
    rgb = np.asarray(canvas.buffer_rgba())[..., :3]
    image = Image.fromarray(np.ascontiguousarray(rgb)).quantize(256, method=Image.Quantize.MAXCOVERAGE)
    buf = io.BytesIO()
    image.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def _as_float(value: object, name: str) -> F64:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected a numeric array, found {type(value).__name__}") from exc
    return arr


def _time_axis(t: ArrayLike | None, n: int, name: str) -> tuple[F64, str]:
    if t is None:
        return np.arange(n, dtype=np.float64), "sample index"
    x = _as_float(t, name)
    if x.shape != (n,):
        raise ValueError(f"{name}: expected shape ({n},), found {x.shape}")
    return x, "time [s]"


def _percentiles_over_runs(err: F64, q: tuple[float, ...]) -> list[F64]:
    """Percentiles (linear interpolation, as numpy's default) over axis 0 ignoring NaN;
    all-NaN columns give NaN. Vectorised: numpy's nanpercentile loops over columns in
    Python when NaN are present, which takes seconds for (runs, 1e4, 3) arrays."""
    s = np.sort(err, axis=0)  # NaN sort last
    count = np.sum(~np.isnan(err), axis=0)
    out = []
    for p in q:
        pos = (np.maximum(count, 1) - 1) * (p / 100.0)
        lo = np.floor(pos).astype(np.intp)
        hi = np.minimum(lo + 1, np.maximum(count - 1, 0))
        v_lo = np.take_along_axis(s, lo[None], axis=0)[0]
        v_hi = np.take_along_axis(s, hi[None], axis=0)[0]
        frac = pos - lo
        v = v_lo + (v_hi - v_lo) * frac
        # exact values where no interpolation is needed (keeps inf - inf from giving NaN)
        v = np.where(frac == 0.0, v_lo, v)
        out.append(np.where(count > 0, v, np.nan))
    return out


def _positive(y: F64) -> F64:
    """Non-positive values masked as NaN, for logarithmic axes."""
    return np.where(y > 0, y, np.nan)


def _buckets(n: int, n_buckets: int) -> NDArray[np.intp]:
    return np.unique(np.linspace(0, n, n_buckets + 1).astype(np.intp))[:-1]


def _envelope(x: F64, y: F64, n_buckets: int) -> tuple[F64, F64, F64]:
    """(x, min, max) of y over at most n_buckets consecutive buckets (identity when short).
    NaN is ignored inside a bucket; an all-NaN bucket gives NaN (a gap)."""
    if y.shape[0] <= n_buckets:
        return x, y, y
    starts = _buckets(y.shape[0], n_buckets)
    ends = np.append(starts[1:], y.shape[0])
    xm = 0.5 * (x[starts] + x[ends - 1])
    return xm, np.fmin.reduceat(y, starts), np.fmax.reduceat(y, starts)


def _line(x: F64, y: F64, max_points: int) -> tuple[F64, F64]:
    """A line of at most max_points points that keeps every bucket's min and max (so
    spikes stay visible): each bucket contributes its min at its first x and its max at
    its middle x. Buckets are far narrower than a pixel, so the order is invisible."""
    if y.shape[0] <= max_points:
        return x, y
    starts = _buckets(y.shape[0], max_points // 2)
    ends = np.append(starts[1:], y.shape[0])
    xs = np.empty(2 * starts.size)
    ys = np.empty(2 * starts.size)
    xs[0::2] = x[starts]
    xs[1::2] = x[(starts + ends - 1) // 2]
    ys[0::2] = np.fmin.reduceat(y, starts)
    ys[1::2] = np.fmax.reduceat(y, starts)
    return xs, ys
