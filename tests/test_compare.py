"""The orchestration behind ``windahrs compare`` / ``report`` as library functions: which
filters run, failures collected, and the one alignment with its explicit fallback."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import windahrs as wa
from windahrs.experiments import compare as cmp
from windahrs.experiments.align import describe_alignment, estimate_alignment
from windahrs.filters.base import MissingSensorError
from windahrs.flight import Reference
from windahrs.rotation import quat_conj, quat_from_euler, quat_mul


@pytest.fixture(scope="module")
def sim() -> wa.Flight:
    return wa.simulate("paper", seed=7, duration=8.0, wind=5.0)


@pytest.fixture(scope="module")
def recording(sim: wa.Flight) -> wa.Flight:
    """The simulation as a log: an autopilot reference at 50 Hz, 2 deg off, 20 ms late."""
    tr = sim.truth
    assert tr is not None
    q_mount = quat_conj(quat_from_euler(np.radians([1.0, -1.5, 0.5])))
    ref = Reference(t=tr.t[::4] + 0.02, q_nb=quat_mul(tr.q_nb[::4], q_mount), kind="autopilot")
    return sim.replace(truth=None, reference=ref)


def test_defaults_not_installed_or_lacking_a_sensor_are_left_out_with_a_note(
    sim: wa.Flight, monkeypatch: pytest.MonkeyPatch
) -> None:
    from windahrs.filters import registry

    installed = [n for n in registry.names() if n != "vqf"]
    monkeypatch.setattr(registry, "names", lambda: installed)
    sel = cmp.select_estimators(None)
    assert list(sel.estimators) == ["auto", "mekf", "ins-wind"] and not sel.explicit
    assert sel.notes == (f"Default filter vqf left out: it {cmp.NOT_INSTALLED}.",)
    asked = cmp.select_estimators(["mekf", "vqf"])
    assert list(asked.estimators) == ["mekf"] and asked.failures == {"vqf": cmp.NOT_INSTALLED}
    no_gnss = sim.replace(gnss=None)
    kept = sel.for_flight(no_gnss)
    assert list(kept.estimators) == ["auto", "mekf"]
    assert kept.notes[1].startswith("Default filter ins-wind left out: filter 'ins-wind' needs GNSS velocity")
    assert asked.for_flight(no_gnss) is asked  # explicit filters are run and fail instead
    with pytest.raises(ValueError, match="unknown 'nope'"):
        cmp.select_estimators(["mekf", "nope"])
    with pytest.raises(ValueError, match="filters: expected at least one filter spec"):
        cmp.select_estimators([" "])


def test_run_estimators_stops_or_collects(sim: wa.Flight) -> None:
    no_air = sim.replace(air=None)
    pairs = [("mekf", wa.estimator("mekf")), ("mekf-air", wa.estimator("mekf-air"))]
    calls: list[tuple[int, int]] = []
    results, failures = cmp.run_estimators(no_air, pairs, keep_going=True, progress=lambda *a: calls.append(a))
    assert [s for s, _ in results] == ["mekf"] and calls == [(1, 2), (2, 2)]
    assert failures["mekf-air"].startswith("filter 'mekf-air' needs air data")
    with pytest.raises(MissingSensorError):
        cmp.run_estimators(no_air, pairs)


def test_one_alignment_raises_or_falls_back(sim: wa.Flight, recording: wa.Flight) -> None:
    est = wa.estimator("mekf").run(recording)
    skipped = cmp.align_reference(sim, ("mekf", est))
    assert skipped.alignment is None and skipped.skipped == cmp.nothing_to_align(sim)
    assert "simulation truth" in skipped.skipped and skipped.fields() == {} and skipped.apply(sim) is sim
    done = cmp.align_reference(recording, ("mekf", est))
    assert done.text == describe_alignment(estimate_alignment(est, recording), "mekf")
    assert done.fields()["aligned_on"] == "mekf" and done.warning is None
    assert sim.truth is not None
    perfect = wa.Estimate("perfect", sim.truth.t, sim.truth.q_nb)
    exact = cmp.align_reference(recording, ("perfect", perfect))
    assert exact.fields()["time_offset_s"] == pytest.approx(0.02, abs=1e-4)
    assert exact.alignment is not None and exact.alignment.mount_angle_deg == pytest.approx(1.9, abs=0.1)
    # a reference that does not overlap the estimate in time cannot be aligned
    ref = recording.reference
    assert ref is not None
    far = recording.replace(reference=Reference(t=ref.t + 1000.0, q_nb=ref.q_nb, kind="autopilot"))
    with pytest.raises(cmp.AlignmentError) as info:
        cmp.align_reference(far, ("mekf", est))
    assert str(info.value) == f"align: {info.value.reason}"
    fell = cmp.align_reference(far, ("mekf", est), fallback=True)
    assert fell.alignment is None and fell.failed == info.value.reason


def test_compare_aligned_prints_the_alignment_then_the_table(recording: wa.Flight) -> None:
    res = wa.compare(recording, ["mekf", "ins-wind"], align=True)
    text = str(res).splitlines()
    assert text[0] == res.alignment.text and text[1] == "RMSE in deg against autopilot (aligned); from sample 50 | " \
        "second half"
    assert "\n".join(text[1:]) == res.table()
    rows = res.as_json()
    assert [r["aligned_on"] for r in rows] == ["mekf", "mekf"]
    plain = wa.compare(recording, ["mekf"])
    assert not plain.aligned and plain.rows[0].rmse_total_deg > res.rows[0].rmse_total_deg


def test_run_for_report_notes_a_failed_alignment(recording: wa.Flight) -> None:
    ref = recording.reference
    assert ref is not None
    far = recording.replace(reference=Reference(t=ref.t + 1000.0, q_nb=ref.q_nb, kind="autopilot"))
    seen: list[str] = []
    run = cmp.run_for_report(far.replace(air=None), cmp.select_estimators(["mekf", "mekf-air"]), align=True,
                             on_failure=lambda spec, why: seen.append(spec))
    assert [s for s, _ in run.results] == ["mekf"] and seen == ["mekf-air"]
    assert run.alignment.failed and run.notes[-1].startswith("--align: no alignment (")
    assert run.notes[-1].endswith("); scores are against the reference as logged.")
    none = cmp.run_for_report(recording.replace(air=None), cmp.select_estimators(["mekf-air"]))
    assert none.results == [] and none.why_none_ran().startswith("mekf-air: filter 'mekf-air' needs air data")


def test_snapshot_of_an_uncopyable_library_says_so() -> None:
    pytest.importorskip("imufusion", reason="imufusion is an optional baseline")
    s = wa.estimator("imufusion").stream()
    s.imu(0.0, np.zeros(3), np.array([0.0, 0.0, -9.8]))
    s.imu(0.01, np.zeros(3), np.array([0.0, 0.0, -9.8]))
    with pytest.raises(TypeError, match="snapshot: the imufusion streamer holds state that cannot be copied"):
        s.snapshot()


def test_a_span_without_reference_samples_is_a_dash_and_null_not_nan(
    recording: wa.Flight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A reference ending before the second half (a truncated log): that span's RMSE is NaN
    in the Score, a dash in the table with a footnote, null in the JSON (strict JSON has no
    NaN), 'no reference sample scored' from estimate and a dash in the report; and no
    numpy "Mean of empty slice" warning on the way."""
    import json
    import warnings

    from windahrs.cli import main
    from windahrs.metrics import rmse
    from windahrs.store import save_flight

    ref = recording.reference
    assert ref is not None
    keep = ref.t < recording.imu.t[len(recording.imu.t) // 2 - 10]  # ends before the second half
    early = recording.replace(reference=Reference(t=ref.t[keep], q_nb=ref.q_nb[keep], kind="autopilot"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert np.isnan(rmse(np.zeros((0, 3)))).all() and rmse(np.zeros((0, 3))).shape == (3,)
        res = cmp.compare(early, "mekf")
    row = res.rows[0]
    assert np.isnan(row.rmse_steady_deg).all() and np.isfinite(row.rmse_total_deg)
    table = res.table()
    assert table.splitlines()[2].split()[4:8] == ["|", "-", "-", "-"]
    assert table.endswith("(-: no reference sample scored in that span)")
    out = json.loads(json.dumps(res.as_json(), allow_nan=False))
    assert out[0]["rmse_steady_deg"] == [None, None, None] and out[0]["rmse_total_deg"] == row.rmse_total_deg
    assert "(-:" not in cmp.compare(recording, "mekf").table()  # a full reference: no footnote

    path = save_flight(early, tmp_path / "early.h5")
    assert main(["compare", str(path), "--filters", "mekf", "--json"]) == 0
    std = capsys.readouterr()
    assert json.loads(std.out)[0]["rmse_steady_deg"] == [None, None, None] and "empty slice" not in std.err
    assert main(["estimate", str(path), "--filter", "mekf"]) == 0
    std = capsys.readouterr()
    assert std.out.rstrip().endswith("; second half: no reference sample scored") and "nan" not in std.out
    assert "empty slice" not in std.err
    assert main(["report", str(path), "--filters", "mekf,ekf7", "--out", str(tmp_path / "r.html")]) == 0
    page = (tmp_path / "r.html").read_text()
    assert "(–: no reference sample scored in that span)" in page and ">nan<" not in page


def test_estimate_keeps_its_output_when_the_reference_misses_the_flight(
    recording: wa.Flight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A reference wholly after the IMU's samples: estimate writes its Estimate and says
    there is nothing to score (it used to print 'wrote' and then fail, its file removed)."""
    from windahrs.cli import main
    from windahrs.store import save_flight

    ref = recording.reference
    assert ref is not None
    later = recording.replace(reference=Reference(t=ref.t + 1000.0, q_nb=ref.q_nb, kind="autopilot"))
    path = save_flight(later, tmp_path / "later.h5")
    out = tmp_path / "est.h5"
    assert main(["estimate", str(path), "--filter", "mekf", "--out", str(out)]) == 0
    assert out.is_file()
    assert capsys.readouterr().out.splitlines()[-1] == (
        "nothing to score: reference: no sample overlaps the estimate in time"
    )
    assert main(["compare", str(path), "--filters", "mekf"]) == 2  # compare has nothing to show: an error
    assert "no sample overlaps the estimate in time" in capsys.readouterr().err


def test_auto_says_in_json_which_estimator_it_ran(recording: wa.Flight) -> None:
    """``--json`` rows of ``compare`` and ``bench-data`` name the estimator ``auto`` chose (it
    was on stderr only), and other filters' rows carry no such field."""
    import json

    from windahrs.experiments.benchdata import TrialScore

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = cmp.compare(recording, ["mekf", "auto"])
    rows = json.loads(json.dumps(res.as_json(), allow_nan=False))
    assert "ran" not in rows[0]
    assert rows[1]["filter"] == "auto" and rows[1]["ran"] == "ins-wind"  # the paper flight has GNSS
    assert set(rows[1]["sensors"].split(",")) >= {"imu", "gnss"}
    row = TrialScore("t", "auto", 1.0, 0.5, 0.8, 10, 0.1, ran="mekf").as_dict()
    assert row["ran"] == "mekf" and list(row)[:2] == ["trial", "filter"]
    assert "ran" not in TrialScore("t", "mekf", 1.0, 0.5, 0.8, 10, 0.1).as_dict()


def test_the_header_says_when_a_heading_offset_was_removed(recording: wa.Flight) -> None:
    ref = recording.reference
    assert ref is not None
    mocap = recording.replace(reference=Reference(t=ref.t, q_nb=ref.q_nb, kind="mocap", heading_free=True))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        free, logged = cmp.compare(mocap, "mekf"), cmp.compare(recording, "mekf")
    assert "a constant heading offset removed per filter" in free.table().splitlines()[0]
    assert "heading offset" not in logged.table()
