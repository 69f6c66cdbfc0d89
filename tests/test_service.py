"""Identification service: period assembly, steady state, exact replay, skipping under load."""

from __future__ import annotations

import time

import numpy as np
import pytest
from scipy import signal

from fnsi_lab.daq.acquisition import Tap, acquire
from fnsi_lab.daq.channels import ChannelInfo
from fnsi_lab.daq.multisine import multisine
from fnsi_lab.daq.recording import Recorder
from fnsi_lab.daq.recording.reader import read_periodic
from fnsi_lab.daq.sources.array_source import ArraySource
from fnsi_lab.replay.service import IdentService
from fnsi_lab.replay.assembly import PeriodAssembler
from fnsi_lab.replay.identifiers import auto_identifier, frf_identifier
from fnsi_lab.viewer.views import auto_view
from fnsi_lab.replay.source import ReplaySource

FS, N = 500.0, 512
CHANNELS = (ChannelInfo("F-A-Z", "force", node="A", direction="Z"),
            ChannelInfo("A-Z", node="A", direction="Z"),
            ChannelInfo("B-Z", node="B", direction="Z"))


def two_dof(n_periods: int, *, noise: float = 0.0, seed: int = 0) -> tuple[np.ndarray, dict]:
    """float32 (samples, 3): force and two displacements of a damped 2-DOF chain."""
    ms = multisine(N, FS, (2.0, 60.0), 1.0, n_periods=n_periods, seed=seed)
    k = np.array([[2e4, -1e4], [-1e4, 1e4]])
    c = 0.002 * k + 0.5 * np.eye(2)
    a = np.block([[np.zeros((2, 2)), np.eye(2)], [-k, -c]])
    b = np.array([[0.0], [0.0], [1.0], [0.0]])
    sysd = signal.cont2discrete((a, b, np.c_[np.eye(2), np.zeros((2, 2))], np.zeros((2, 1))),
                                1 / FS)
    _, y, _ = signal.dlsim((*sysd[:4], 1 / FS), ms.signal[0])
    y = y + noise * np.std(y) * np.random.default_rng(seed).standard_normal(y.shape)
    exc = {"kind": "multisine", "band_hz": [2.0, 60.0], "rms": 1.0, "samples_per_period": N,
           "periods": n_periods, "transient_periods": 1, "realizations": 1, "seed": seed,
           "phases": "random", "sample_rate_hz": FS}
    return np.c_[ms.signal[0], y].astype(np.float32), {"excitation": exc}


def record(path, data, metadata, block_size=100):
    with Recorder(path, CHANNELS, FS, metadata=metadata) as rec:
        for b in ArraySource(data, CHANNELS, FS, block_size=block_size):
            rec.write_block(b)
    return path


# ---------------------------------------------------------------------------- assembly
def test_assembler_cuts_periods_across_blocks_and_skips_partial_ones(channels):
    from conftest import blocks_from_array, periodic_signal

    data = periodic_signal(channels, 100, 5, seed=1)
    blocks = blocks_from_array(data, channels, 1000.0, 37)  # blocks straddle periods
    asm = PeriodAssembler(100, len(channels))
    periods = [p for b in blocks for p in asm.add(b)]
    assert [p.index for p in periods] == [0, 1, 2, 3, 4]
    for p in periods:
        assert np.array_equal(p.data, data[p.index * 100:(p.index + 1) * 100])
    assert periods[2].end_ns == 300_000_000
    # a lost block: the period it falls in is dropped, the next ones are complete
    asm = PeriodAssembler(100, len(channels))
    kept = [b for i, b in enumerate(blocks) if i != 4]  # samples 148..184 lost
    periods = [p for b in kept for p in asm.add(b)]
    assert [p.index for p in periods] == [0, 2, 3, 4]
    assert asm.lost_samples == 37 and asm.gaps == 1
    # starting mid-period (a replay from an offset): the first partial period is skipped
    asm = PeriodAssembler(100, len(channels))
    assert [p.index for b in blocks[2:] for p in asm.add(b)] == [1, 2, 3, 4]


def test_steady_state_detection_waits_for_periodicity(channels):
    from conftest import blocks_from_array, periodic_signal

    data = periodic_signal(channels, 100, 6, seed=2).astype(np.float64)
    decay = np.exp(-np.arange(data.shape[0]) / 30.0)[:, None]  # transient over ~3 periods
    data = data + 5 * decay * np.random.default_rng(0).standard_normal(data.shape)
    svc = IdentService(channels, 1000.0, 100, frf_identifier, steady_state_tolerance=1e-3)
    svc.run(blocks_from_array(data, channels, 1000.0, 50))
    first = svc.updates[0].record
    assert first.transient_periods >= 3  # detected, not given
    assert svc.status.periods == 6 and svc.status.steady_periods == 6 - first.transient_periods


# ---------------------------------------------------------------------------- exactness
def test_final_snapshot_equals_read_periodic_of_the_recording(tmp_path):
    data, meta = two_dof(5)
    path = record(tmp_path / "r.mcap", data, meta, block_size=70)
    with ReplaySource(path) as src:
        svc = IdentService.for_recording_metadata(src.channels, src.sample_rate_hz,
                                                  src.metadata, frf_identifier)
        svc.run(src)
    offline = read_periodic(path)
    live = svc.updates[-1].record
    assert live.transient_periods == offline.transient_periods == 1
    assert np.array_equal(live.u, offline.u) and np.array_equal(live.y, offline.y)
    assert np.array_equal(live.excited_lines, offline.excited_lines)
    # estimates improve as periods accumulate: one update per steady period
    assert [u.n_periods for u in svc.updates] == [1, 2, 3, 4]


def test_replay_reproduces_the_identification_of_the_original_data_exactly(tmp_path):
    data, meta = two_dof(4, noise=0.01)
    identify = auto_identifier(orders=range(2, 7))
    # original data, straight from the source (as in a live run)
    original = IdentService(CHANNELS, FS, N, identify, transient_periods=1,
                            excited_lines=multisine(N, FS, (2.0, 60.0), 1.0).excited_lines)
    original.run(ArraySource(data, CHANNELS, FS, block_size=100))
    # the recording of the same data, replayed through the threaded service
    path = record(tmp_path / "r.mcap", data, meta)
    src = ReplaySource(path)
    replayed = IdentService.for_recording_metadata(src.channels, src.sample_rate_hz,
                                                   src.metadata, identify).start(src)
    replayed.finish()
    src.close()
    a, b = original.updates[-1].result.result, replayed.updates[-1].result.result
    assert replayed.updates[-1].n_periods == original.updates[-1].n_periods == 3
    assert a.selected_order == b.selected_order
    assert np.array_equal(a.information_criterion.value, b.information_criterion.value)
    assert np.array_equal(a.model.a_d, b.model.a_d) and np.array_equal(a.model.b_d, b.model.b_d)
    assert np.array_equal(a.modal_dominancy.mdi, b.modal_dominancy.mdi)
    assert np.array_equal(a.physical, b.physical)
    # and the view of it has the poles, MDI and criterion the viewer needs
    view = auto_view(replayed.updates[-1])
    assert view["criterion"]["selected_order"] == a.selected_order
    assert len(view["mdi"]["mdi"]) == len(a.modal_dominancy.mdi)
    f_true = 9.836  # first natural frequency of the chain (Hz)
    assert np.min(np.abs(np.asarray(view["convergence"]["values"]["natural_frequency_hz"])
                         - f_true)) < 0.01


def test_replay_and_ident_give_one_answer_on_one_recording(tmp_path):
    """Issue 28: the replayed (= live) identification and ``fnsi-lab ident --auto`` resolve
    the same request (ident.request): the same default sweep (2..60, where replay used
    2..40), so the same order, modes and criterion on the same recording."""
    import json

    from fnsi_lab.cli import main
    from fnsi_lab.ident.request import DEFAULT_ORDERS
    from fnsi_lab.replay.identifiers import config_identifier

    data, meta = two_dof(4, noise=0.01)
    path = record(tmp_path / "r.mcap", data, meta)
    src = ReplaySource(path)
    identify, what = config_identifier(None, channels=src.channels)
    assert f"orders {DEFAULT_ORDERS[0]}-{DEFAULT_ORDERS[-1]}" in what
    service = IdentService.for_recording_metadata(src.channels, src.sample_rate_hz,
                                                  src.metadata, identify).start(src)
    service.finish()
    src.close()
    live = service.updates[-1].result.identification.to_json()
    assert main(["ident", str(path), "--auto", "--json", str(tmp_path / "r.json")]) == 0
    offline = json.loads((tmp_path / "r.json").read_text())
    assert [r["order"] for r in live["information_criterion"]] == list(DEFAULT_ORDERS)
    assert live["order"] == offline["order"]
    assert [m["frequency_hz"] for m in live["modes"]] == pytest.approx(
        [m["frequency_hz"] for m in offline["modes"]], rel=1e-9)


# ---------------------------------------------------------------------------- load
def test_fast_source_slow_identification_skips_cleanly_and_recording_is_complete(tmp_path):
    """A source far faster than real time, an identification that takes 0.15 s."""
    data, meta = two_dof(12)
    calls: list[int] = []

    def slow(record):
        calls.append(record.n_periods)
        time.sleep(0.15)
        return frf_identifier(record)

    src = ArraySource(data, CHANNELS, FS, block_size=50)
    tap = Tap("ident", maxsize=64)
    svc = IdentService(CHANNELS, FS, N, slow, transient_periods=1,
                       excited_lines=multisine(N, FS, (2.0, 60.0), 1.0).excited_lines)
    svc.start(tap)
    path = tmp_path / "fast.mcap"
    with src, Recorder(path, CHANNELS, FS, metadata=meta) as rec:
        report = acquire(src, rec, taps=[tap], live=True)
    t0 = time.perf_counter()
    status = svc.finish(timeout=30)
    assert time.perf_counter() - t0 < 10
    # acquisition and recording never waited and lost nothing
    assert report.recorder_overflows == 0
    assert report.blocks == data.shape[0] // 50 + (data.shape[0] % 50 > 0)
    offline = read_periodic(path)
    assert offline.n_periods == 12
    assert np.array_equal(offline.u[0].reshape(-1), data[:, 0].astype(np.float64))
    # the service skipped to the newest data and said so
    assert status.updates == len(calls) and status.updates >= 1
    assert status.updates < 11  # 11 steady periods, fewer identifications
    assert status.skipped + status.updates <= 11
    assert status.dropped_blocks == report.tap_drops["ident"]
    assert status.blocks + status.dropped_blocks == report.blocks
    # every identified record holds consecutive periods only
    for u in svc.updates:
        assert u.record.u.shape[1] == u.n_periods + u.record.transient_periods
    line = status.line(file_size_bytes=path.stat().st_size)
    assert "skipped" in line and "dropped" in line and "MB" in line
    # ... and that it could not keep up: 0.15 s per identification against periods arriving
    # every few milliseconds
    assert status.update_budget_s < 0.15 and status.behind >= 1 and "BEHIND" in line


def test_service_keeps_up_with_a_real_time_source():
    data, meta = two_dof(4)
    src = ArraySource(data, CHANNELS, FS, block_size=50, pace=20.0)  # 20x real time
    tap = Tap("ident", maxsize=256)
    svc = IdentService(CHANNELS, FS, N, frf_identifier, transient_periods=1,
                       excited_lines=multisine(N, FS, (2.0, 60.0), 1.0).excited_lines).start(tap)
    with src:
        acquire(src, None, taps=[tap])
    st = svc.finish(timeout=10)
    assert st.dropped_blocks == 0 and st.skipped == 0 and st.lost_samples == 0
    assert st.updates == 3 and st.max_latency_s < 1.0
    # periods arrive every N / fs / 20 = 51 ms; the FRF identification takes milliseconds
    assert 0.5 * N / FS / 20 < st.period_interval_s < 2 * N / FS / 20
    assert st.behind == 0 and st.keeping_up and "BEHIND" not in st.line()


def test_failures_are_counted_not_raised(channels):
    from conftest import blocks_from_array, periodic_signal

    def broken(record):
        raise ValueError("boom")

    svc = IdentService(channels, 1000.0, 100, broken)
    svc.run(blocks_from_array(periodic_signal(channels, 100, 3), channels, 1000.0, 50))
    assert svc.status.failures == 3 and "boom" in svc.status.last_error
    assert svc.status.updates == 0


def test_unknown_period_is_a_named_error(channels):
    from fnsi_lab.errors import ConfigError

    with pytest.raises(ConfigError, match="period length is unknown"):
        IdentService.for_recording_metadata(channels, 1000.0, {}, frf_identifier)


def test_a_failing_source_is_reraised_by_finish_after_identifying_what_arrived(channels):
    from conftest import blocks_from_array, periodic_signal

    blocks = blocks_from_array(periodic_signal(channels, 100, 3), channels, 1000.0, 50)

    def source():
        yield from blocks[:4]  # two complete periods
        raise OSError("device gone")

    svc = IdentService(channels, 1000.0, 100, frf_identifier).start(source())
    with pytest.raises(OSError, match="device gone"):
        svc.finish(timeout=10)
    assert svc.status.updates >= 1 and svc.updates[-1].n_periods == 2
