"""The registry: every estimator by name, for the CLI, benchmarks and experiments.

Every windahrs estimator runs on the compiled core (:mod:`windahrs.core`).

Entries are imported lazily so that an outside library (ahrs, vqf, imufusion) is only
needed when its adapter is used.
"""

from __future__ import annotations

import dataclasses
import importlib
from pathlib import Path

from windahrs.filters.base import Estimator

__all__ = ["REGISTRY", "SMOOTH_SUFFIX", "make_estimator", "names", "with_overrides"]

#: A registry name with this suffix is that estimator's offline smoother (make_estimator).
SMOOTH_SUFFIX = "-smooth"

#: name -> (module, class, one-line description)
REGISTRY: dict[str, tuple[str, str, str]] = {
    "auto": ("windahrs.filters.auto", "Auto", "ins-wind with GNSS velocity, else mekf: what the sensors allow"),
    "paper": ("windahrs.filters.paper", "PaperEKF", "the paper's EKF, faithful, with air-flow direction"),
    "paper-nowind": ("windahrs.filters.paper", "PaperEKFNoWind", "the paper's EKF without the air data"),
    "ekf": ("windahrs.filters.ekf", "TraditionalEKF", "traditional accelerometer+magnetometer EKF"),
    "ukf": ("windahrs.filters.ukf", "AdditiveUKF", "additive-quaternion UKF"),
    "ekf7": ("windahrs.filters.ekf7", "Ekf7", "additive quaternion + gyro bias EKF, Q from gyro noise"),
    "ekf10": ("windahrs.filters.ekf7", "Ekf10", "ekf7 plus wind states fusing air data"),
    "mekf": ("windahrs.filters.eskf", "Mekf", "error-state EKF, attitude + gyro bias"),
    "mekf-air": ("windahrs.filters.eskf", "MekfAir", "error-state EKF with wind states and air data"),
    "ins-wind": ("windahrs.filters.eskf", "InsWind", "error-state INS with wind states (recommended)"),
    "ins-drag": ("windahrs.filters.eskf", "InsDrag", "ins-wind fusing multirotor drag: wind without a pitot"),
    "usque": (
        "windahrs.filters.usque",
        "Usque",
        "error-state unscented filter (USQUE), GRP attitude error + gyro bias",
    ),
    "ahrs-ekf": ("windahrs.baselines", "AhrsEkf", "ahrs package EKF"),
    "madgwick": ("windahrs.baselines", "Madgwick", "ahrs package Madgwick"),
    "mahony": ("windahrs.baselines", "Mahony", "ahrs package Mahony"),
    "vqf": ("windahrs.baselines", "Vqf", "vqf package VQF"),
    "vqf-offline": ("windahrs.baselines", "VqfOffline", "vqf package offline VQF (non-causal, no streaming)"),
    "imufusion": ("windahrs.baselines", "ImuFusion", "imufusion (x-io Fusion) AHRS"),
}


def names() -> list[str]:
    """Registered estimator names whose implementation is importable."""
    out = []
    for name, (module, cls, _) in REGISTRY.items():
        try:
            getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError):
            continue
        out.append(name)
    return out


def _number(text: str) -> int | float | None:
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return None


#: The separator of a vector's components in a filter spec (``mean_wind_n=3/-2/0``): the
#: spec's own separators are ``:`` (fields) and ``,`` (specs in ``--filters a,b``), and
#: ``/`` needs no quoting in a shell (``;`` and ``[...]`` do).
VECTOR_SEP = "/"


def _value(text: str, key: str = "", spec: str = "") -> object:
    """A spec value: true/false, an int, a float, a vector of numbers ``a/b/c`` (a tuple),
    else the text. ValueError naming the field and the value for a vector with a part that
    is not a number."""
    if VECTOR_SEP in text:
        parts = [p.strip() for p in text.split(VECTOR_SEP)]
        nums = [_number(p) for p in parts]
        bad = [p for p, v in zip(parts, nums, strict=True) if v is None]
        if bad:
            raise ValueError(
                f"filter {spec!r}: {key}: expected numbers separated by {VECTOR_SEP!r} (e.g. {key}=3/-2/0), "
                f"found {text!r} ({bad[0]!r} is not a number)"
            )
        return tuple(nums)
    low = text.lower()
    if low in ("true", "false"):
        return low == "true"
    num = _number(text)
    return text if num is None else num


def make_estimator(spec: str, params_file: str | Path | None = None) -> Estimator:
    """Build an estimator from a spec ``NAME`` or ``NAME:field=value:field=value`` (fields of
    its parameter record, e.g. ``paper:wind=mean`` or ``mekf:mag_mode=heading``; a vector
    field's components separated by ``/``, e.g. ``paper:wind=mean:mean_wind_n=3/-2/0``),
    with parameters from a TOML file first when given. ``NAME-smooth`` or ``smooth=true``: its
    offline smoother (:mod:`windahrs.core.smooth`; e.g. ``auto-smooth``,
    ``mekf:mag_mode=heading:smooth=true``), ValueError for an estimator it cannot smooth;
    ``smoother=two-filter`` or ``smoother=rts`` (implies ``smooth=true``) chooses the method,
    ``auto`` by default (:func:`windahrs.core.smooth.smooth`).

    Unknown names raise ValueError listing the known ones; unknown fields name the field.
    """
    name, *assignments = spec.split(":")
    overrides: dict[str, object] = {}
    for a in assignments:
        key, sep, val = a.partition("=")
        if not sep or not key:
            raise ValueError(f"filter {spec!r}: expected NAME:field=value, found {a!r}")
        overrides[key.strip()] = _value(val.strip(), key.strip(), spec)
    smooth = overrides.pop("smooth", False)
    if not isinstance(smooth, bool):
        raise ValueError(f"filter {spec!r}: smooth: expected true or false, found {smooth!r}")
    method = overrides.pop("smoother", None)
    if method is not None:
        from windahrs.core.smooth import check_method

        check_method(method, f"filter {spec!r}: smoother")
        smooth = True
    if name.endswith(SMOOTH_SUFFIX) and name not in REGISTRY:
        name, smooth = name[: -len(SMOOTH_SUFFIX)], True
    est = _build(name, params_file)
    if overrides:
        est = with_overrides(est, name, overrides)
        est.label = spec
    if smooth:
        from windahrs.core.smooth import Smoothed

        return Smoothed(est, label=spec, method=str(method or "auto"))
    if ":" in spec:
        est.label = spec
    return est


def with_overrides(est: Estimator, name: str, overrides: dict[str, object]) -> Estimator:
    """A new estimator of ``est``'s type with ``overrides`` (field -> value) on its
    parameters. An estimator with a ``with_overrides`` method (``auto``, which passes fields
    on to the estimator it chooses) applies them itself; otherwise each field must be one
    its ``param_names`` lists (ValueError naming the field and the filter)."""
    own = getattr(est, "with_overrides", None)
    if own is not None:
        built: Estimator = own(overrides)
        return built
    params = getattr(est, "params", None)
    if params is None or not dataclasses.is_dataclass(params):
        raise ValueError(f"filter {name!r} takes no parameters, found {sorted(overrides)}")
    every = {f.name for f in dataclasses.fields(params)}
    known = set(getattr(est, "param_names", lambda: every)())
    for key in overrides:
        if key not in known:
            what = "does not use" if key in every else "has no"
            raise ValueError(
                f"filter {name!r} {what} parameter {key!r}; its parameters: {', '.join(sorted(known))}"
            )
    return type(est)(dataclasses.replace(params, **overrides))  # type: ignore[call-arg, type-var]


def _build(name: str, params_file: str | Path | None) -> Estimator:
    if name not in REGISTRY:
        raise ValueError(f"filter: unknown {name!r}; known filters: {', '.join(names())}")
    module, cls_name, _ = REGISTRY[name]
    try:
        cls = getattr(importlib.import_module(module), cls_name)
    except ImportError as exc:
        raise ValueError(
            f"filter {name!r} needs a package that is not installed ({exc.name}): "
            "pip install 'windahrs[baselines]'"
        ) from None
    if params_file is None:
        return cls()
    load = getattr(cls, "load_params", None)
    if load is None:
        from windahrs.filters.params import load_params

        base = getattr(cls, "default_params", None)
        allowed = cls.param_names() if hasattr(cls, "param_names") else None
        return cls(load_params(params_file, base, allowed=allowed, filter_name=name))
    return cls(load(params_file))
