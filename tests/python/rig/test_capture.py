"""Merging traces by period: loss and duplicate detection, instant-of-claim alignment."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hiltest_support import TS, Synthetic

from rig.data import capture


def _build(tmp: Path, syn: Synthetic, expected: bool = True, **kw):  # type: ignore[no-untyped-def]
    plant, fw = syn.write(tmp, **kw)
    exp = (0, syn.n - 1) if expected else None
    return capture.build(tmp / "cap", capture.default_specs(plant, fw), expected=exp,
                         pole_pairs=syn.pole_pairs, chunk=512)


def test_complete_capture_has_no_loss_and_expected_columns(tmp_path: Path) -> None:
    syn = Synthetic(n=1500, error_deg=lambda t: np.full_like(t, 1.25))
    cap, loss = _build(tmp_path, syn)
    assert loss.ok and loss.lost == 0 and loss.duplicates == 0
    assert (cap.first_period, cap.n) == (0, 1500)
    np.testing.assert_array_equal(cap["period"], np.arange(1500))
    err = np.asarray(cap["pos_err_deg"])
    # every row has a truth pair except where the claimed instant lies past the last period
    assert np.isnan(err[-1]) and not np.isnan(err[:-1]).any()
    np.testing.assert_allclose(err[:-1], 1.25, atol=2e-4)
    np.testing.assert_allclose(cap["speed_true_rpm"], syn.speed_rpm, rtol=1e-6)
    np.testing.assert_allclose(cap["speed_hat_rpm"], syn.speed_rpm, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(cap["speed_err_rpm"])[:-1], 0.0, atol=1e-3)
    np.testing.assert_allclose(cap["v_mag"], 5.0, rtol=1e-6)  # vd 3, vq 4
    # the merged columns survive re-opening from disk
    again = capture.Capture(tmp_path / "cap")
    np.testing.assert_array_equal(again["fw.theta_hat"], cap["fw.theta_hat"])


def test_error_is_taken_at_the_instant_the_estimate_claims(tmp_path: Path) -> None:
    # stamps anywhere from half a period before to 1.5 periods after the period start;
    # theta_hat is exact at its stamp, so the aligned error is zero. Comparing at the period
    # start instead would be off by omega_e * stamp.
    stamps = lambda k: ((k * 7919) % 20000) - 5000  # noqa: E731
    syn = Synthetic(n=2000, speed_rpm=2400.0, stamp=stamps)
    cap, loss = _build(tmp_path, syn)
    assert loss.ok
    err = np.asarray(cap["pos_err_deg"])
    ok = ~np.isnan(err)
    assert ok.sum() >= 1995
    assert np.abs(err[ok]).max() < 2e-3
    naive = math.degrees(syn.omega_e) * np.asarray(cap["fw.stamp"]) * 10e-9
    assert np.abs(naive).max() > 4.0  # the alignment matters at this speed


def test_theta_is_unwrapped_across_chunks(tmp_path: Path) -> None:
    syn = Synthetic(n=3000, speed_rpm=3000.0)
    cap, _ = _build(tmp_path, syn)
    unw = np.asarray(cap["truth.theta_unwrapped"])
    expected = syn.theta_true(np.arange(3000) * TS)
    expected = expected - expected[0] + unw[0]
    np.testing.assert_allclose(unw, expected, atol=1e-5)


def test_forced_loss_is_detected_with_counts(tmp_path: Path) -> None:
    syn = Synthetic(n=1000)
    cap, loss = _build(tmp_path, syn, drop={"truth": [100], "fw": [200, 201, 202, 203, 204]})
    assert not loss.ok
    by = {m.message: m for m in loss.messages}
    assert by["BENCH_TRUTH"].missing == 1
    assert by["BENCH_TRUTH_MAG"].missing == 0
    assert by["FW_TRACE"].missing == 5
    assert loss.lost == 6
    assert "6 missing" in loss.summary()
    # the lost rows are NaN, never silently zero
    assert np.isnan(cap["truth.theta_e"][100]) and np.isnan(cap["fw.theta_hat"][202])
    assert not np.isnan(cap["fw.theta_hat"][199])


def test_duplicates_are_detected(tmp_path: Path) -> None:
    syn = Synthetic(n=500)
    _, loss = _build(tmp_path, syn, dup={"mag": [10, 11], "fw": [499]})
    assert not loss.ok and loss.lost == 0
    by = {m.message: m for m in loss.messages}
    assert (by["BENCH_TRUTH_MAG"].duplicates, by["FW_TRACE"].duplicates) == (2, 1)
    assert loss.duplicates == 3


def test_short_traces_against_the_expected_range(tmp_path: Path) -> None:
    syn = Synthetic(n=600)
    plant, fw = syn.write(tmp_path)
    specs = capture.default_specs(plant, fw)
    # the firmware may end one period early (its last ISR races the stop); the plant may not
    _, ok = capture.build(tmp_path / "a", specs, expected=(0, 600))
    assert not ok.ok and ok.short_end == 1  # plant ends at 599, expected 600
    _, tol = capture.build(tmp_path / "b", specs, expected=(0, 599))
    assert tol.ok
    (tmp_path / "c").mkdir()
    p2, f2 = Synthetic(n=600).write(tmp_path / "c", drop={"fw": [599]})
    _, fw_short = capture.build(tmp_path / "d", capture.default_specs(p2, f2), expected=(0, 599))
    assert fw_short.ok and fw_short.last_period == 598
    (tmp_path / "e").mkdir()
    p3, f3 = Synthetic(n=600).write(tmp_path / "e", drop={"fw": [597, 598, 599]})
    _, fw_shorter = capture.build(tmp_path / "f", capture.default_specs(p3, f3), expected=(0, 599))
    assert not fw_shorter.ok and fw_shorter.short_end == 2


def test_partial_record_fails_the_capture(tmp_path: Path) -> None:
    syn = Synthetic(n=200)
    plant, fw = syn.write(tmp_path)
    with fw.open("ab") as fh:
        fh.write(b"\x20\x00")
    _, loss = capture.build(tmp_path / "cap", capture.default_specs(plant, fw), expected=(0, 199))
    assert not loss.ok and loss.trailing_bytes["firmware"] == 2
    assert "partial record" in loss.summary()


def test_chunk_size_does_not_change_the_result(tmp_path: Path) -> None:
    syn = Synthetic(n=1200, error_deg=lambda t: 3 * np.sin(2 * math.pi * 40 * t))
    plant, fw = syn.write(tmp_path)
    specs = capture.default_specs(plant, fw)
    a, _ = capture.build(tmp_path / "a", specs, expected=(0, 1199), chunk=97)
    b, _ = capture.build(tmp_path / "b", specs, expected=(0, 1199), chunk=1 << 16)
    for col in a.columns:
        np.testing.assert_array_equal(a[col], b[col], err_msg=col)


def test_speed_reference_column(tmp_path: Path) -> None:
    syn = Synthetic(n=300)
    plant, fw = syn.write(tmp_path)
    cap, _ = capture.build(tmp_path / "cap", capture.default_specs(plant, fw),
                           speed_reference=lambda t: 1000.0 * t)
    np.testing.assert_allclose(cap["speed_ref_rpm"], 1000.0 * np.arange(300) * TS)


@pytest.mark.parametrize("missing", ["plant", "fw"])
def test_empty_trace_is_total_loss(tmp_path: Path, missing: str) -> None:
    syn = Synthetic(n=100)
    plant, fw = syn.write(tmp_path)
    target = plant if missing == "plant" else fw
    target.write_bytes(target.read_bytes()[:16])
    _, loss = capture.build(tmp_path / "cap", capture.default_specs(plant, fw), expected=(0, 99))
    assert not loss.ok and loss.lost >= 99  # the firmware's last period is tolerated


def test_capture_on_a_file_system_that_cannot_map_files(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """9p (the VM runner's mount) refuses mmap: the same capture must come out."""
    syn = Synthetic(n=800, error_deg=lambda t: np.full_like(t, 0.75))
    (tmp_path / "mapped").mkdir()
    (tmp_path / "unmappable").mkdir()
    reference, _ = _build(tmp_path / "mapped", syn)
    out = tmp_path / "unmappable" / "cap"
    real_open_memmap = np.lib.format.open_memmap
    real_load = np.load

    def refuse_under_out(path, *a, **kw):  # type: ignore[no-untyped-def]
        if Path(path).parent == out:
            raise OSError(22, "Invalid argument")
        return real_open_memmap(path, *a, **kw)

    def load(path, *a, **kw):  # type: ignore[no-untyped-def]
        if Path(path).parent == out and kw.get("mmap_mode"):
            raise OSError(22, "Invalid argument")
        return real_load(path, *a, **kw)

    monkeypatch.setattr(np.lib.format, "open_memmap", refuse_under_out)
    monkeypatch.setattr(np, "load", load)
    plant, fw = syn.write(tmp_path / "unmappable")
    cap, loss = capture.build(out, capture.default_specs(plant, fw), expected=(0, syn.n - 1),
                              pole_pairs=syn.pole_pairs, chunk=512)
    assert loss.ok
    assert sorted(p.name for p in out.glob("*.npy")) == sorted(
        f"{c}.npy" for c in reference.keys())
    for col in ("period", "fw.theta_hat", "pos_err_deg", "speed_true_rpm"):
        np.testing.assert_array_equal(np.asarray(cap[col]), np.asarray(reference[col]))


def _append_fw_records(fw: Path, periods: list[int]) -> None:
    """Raw FW_TRACE records at the end of a trace (what a hijacked firmware wrote)."""
    import struct

    from rig import protocols

    m = protocols.database("vio").get_message_by_name("FW_TRACE")
    with fw.open("ab") as f:
        for p in periods:
            vals = {s.name: 0 for s in m.signals} | {"period": p}
            data = m.encode(vals, strict=False)
            f.write(struct.pack("<IBBBB", m.frame_id, len(data), 4, 0, 0)
                    + data.ljust(64, b"\0"))


def test_records_far_outside_the_run_are_counted_in_bounded_memory(tmp_path: Path) -> None:
    """Issue 16.1: the counts per period cover the expected range only; a record 3e9
    periods away is a loss that fails the run, not a 3e9-entry array (23 GiB)."""
    syn = Synthetic(n=800)
    plant, fw = syn.write(tmp_path)
    _append_fw_records(fw, [3_000_000_000 + k for k in range(20)])
    cap, loss = capture.build(tmp_path / "cap", capture.default_specs(plant, fw),
                              expected=(0, syn.n - 1), pole_pairs=syn.pole_pairs, chunk=512,
                              max_span=10 * syn.n)
    assert not loss.ok
    by = {m.message: m for m in loss.messages}
    assert by["FW_TRACE"].outside == 20 and by["FW_TRACE"].missing == 0
    assert by["BENCH_TRUTH"].outside == 0
    assert "20 records outside" in loss.summary()
    assert cap.n == syn.n


def test_an_absurd_span_without_an_expected_range_fails_cleanly(tmp_path: Path) -> None:
    syn = Synthetic(n=500)
    plant, fw = syn.write(tmp_path)
    _append_fw_records(fw, [3_000_000_000])
    with pytest.raises(capture.CaptureSpanError, match="3000000000"):
        capture.build(tmp_path / "cap", capture.default_specs(plant, fw), expected=None,
                      pole_pairs=syn.pole_pairs, chunk=512, max_span=10 * syn.n)
