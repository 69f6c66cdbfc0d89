"""Shared fixtures: synthetic channels and blocks, and small MCAP recordings on tmp_path."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

import numpy as np
import pytest

from fnsi_lab.daq.block import Block
from fnsi_lab.daq.channels import ChannelInfo


def make_channels(n_outputs: int = 3, n_inputs: int = 1) -> tuple[ChannelInfo, ...]:
    """``n_inputs`` force channels followed by ``n_outputs`` displacement channels."""
    forces = [ChannelInfo(f"F{i}", "force", node=f"N{i}", direction="Z") for i in range(n_inputs)]
    outs = [ChannelInfo(f"X{i}", "displacement", node=f"N{i}", direction="Z")
            for i in range(n_outputs)]
    return tuple(forces + outs)


def periodic_signal(channels: tuple[ChannelInfo, ...], samples_per_period: int, n_periods: int,
                    *, seed: int = 0, noise: float = 0.0) -> np.ndarray:
    """float32 array (n_periods * N, n_channels): one random period repeated, plus noise."""
    rng = np.random.default_rng(seed)
    period = rng.standard_normal((samples_per_period, len(channels)))
    x = np.tile(period, (n_periods, 1))
    if noise:
        x = x + noise * rng.standard_normal(x.shape)
    return x.astype(np.float32)


def blocks_from_array(data: np.ndarray, channels: tuple[ChannelInfo, ...], sample_rate_hz: float,
                      block_size: int, *, realization: int = 0, first_sequence: int = 0,
                      t_offset_ns: int = 0) -> list[Block]:
    """Cut (n_samples, n_channels) into Blocks as a source would deliver them."""
    blocks = []
    for k, start in enumerate(range(0, data.shape[0], block_size)):
        blocks.append(Block(data=data[start:start + block_size], channels=channels,
                            sample_rate_hz=sample_rate_hz, sequence=first_sequence + k,
                            first_sample=start,
                            t0_ns=t_offset_ns + int(round(start * 1e9 / sample_rate_hz)),
                            realization=realization))
    return blocks


@pytest.fixture(autouse=True)
def _no_leaked_recorders():
    """Fail a test that leaves a daq.recording.Recorder open (its file would be unfinished)."""
    from fnsi_lab.daq.recording.writer import open_recorders
    before = set(map(id, open_recorders()))
    yield
    leaked = [r for r in open_recorders() if id(r) not in before]
    for r in leaked:
        r.close()
    if leaked:
        pytest.fail(f"test left {len(leaked)} Recorder(s) open: {leaked}; use `with Recorder(...)`")


@pytest.fixture
def channels() -> tuple[ChannelInfo, ...]:
    """One force and three displacement channels."""
    return make_channels()


@pytest.fixture
def write_recording(tmp_path: Path) -> Callable[..., tuple[Path, list[Block]]]:
    """Factory writing a small periodic multisine-like recording; returns (path, blocks).

    Keyword arguments: ``name``, ``channels``, ``sample_rate_hz``, ``samples_per_period``,
    ``n_periods``, ``realizations``, ``block_size``, ``metadata`` (merged over a default
    excitation record; ``excitation=None`` drops it), ``attachments``, ``seed``,
    ``noise``, ``extra_samples`` (appended after the last whole period), recorder kwargs.
    """
    from fnsi_lab.daq.recording import Recorder

    def factory(name: str = "rec.mcap", *, channels: tuple[ChannelInfo, ...] | None = None,
                sample_rate_hz: float = 1000.0, samples_per_period: int = 200,
                n_periods: int = 4, realizations: int = 1, block_size: int = 50,
                metadata: dict[str, Any] | None = None, attachments: list | None = None,
                seed: int = 0, noise: float = 0.0, extra_samples: int = 0,
                **recorder_kwargs: Any) -> tuple[Path, list[Block]]:
        chans = channels or make_channels()
        meta: dict[str, Any] = {"excitation": {
            "kind": "multisine", "band_hz": [5.0, 50.0], "rms": 1.0,
            "samples_per_period": samples_per_period, "periods": n_periods,
            "transient_periods": 1, "realizations": realizations, "seed": seed,
            "phases": "random", "sample_rate_hz": sample_rate_hz}}
        meta.update(metadata or {})
        meta = {k: v for k, v in meta.items() if v is not None}
        path = tmp_path / name
        blocks: list[Block] = []
        seq = 0
        t_ns = 0
        for r in range(realizations):
            x = periodic_signal(chans, samples_per_period, n_periods, seed=seed + r, noise=noise)
            if extra_samples:
                x = np.concatenate([x, x[:extra_samples]], axis=0)
            bs = blocks_from_array(x, chans, sample_rate_hz, block_size, realization=r,
                                   first_sequence=seq, t_offset_ns=t_ns)
            seq += len(bs)
            t_ns = bs[-1].end_ns
            blocks += bs
        with Recorder(path, chans, sample_rate_hz, metadata=meta,
                      attachments=attachments or [], **recorder_kwargs) as rec:
            for b in blocks:
                rec.write_block(b)
        return path, blocks

    return factory


@pytest.fixture(autouse=True)
def _blas_threads_restored():
    """Give every test the process's OpenBLAS thread count as it found it (a command run
    in-process, or a test, that sets it must not decide another test's numbers)."""
    from fnsi_lab.blas import restored_blas_threads
    with restored_blas_threads():
        yield


def write_cubic_chain(path: Path, *, rms: float = 20.0, periods: int = 2, seed: int = 1,
                      noise: float = 0.0) -> Path:
    """The 3-DOF chain with its relative cubic spring (``daq.sim.lumped``, k3 = 1e9 N/m^3),
    multisine 3-60 Hz at 500 Hz, ``periods`` periods of 4096, written as an array file
    (displacements X1, X2, X3; force F-X3); ``noise``: white noise, that fraction of each
    output's standard deviation."""
    from fnsi_lab.daq.multisine import multisine
    from fnsi_lab.daq.sim.integrate import simulate
    from fnsi_lab.daq.sim.lumped import lumped_model

    m = lumped_model("cubic")
    ms = multisine(4096, 500.0, (3, 60), rms, n_periods=periods, seed=seed)
    y = simulate(m, ms.signal[0][:, None], 500.0, periodic=4096,
                 quantities=("displacement",)).displacement
    if noise:
        y = y + noise * y.std(axis=0) * np.random.default_rng(seed).standard_normal(y.shape)
    np.savez(path, u=ms.signal[0][:, None], y=y, fs=500.0, N=4096,
             channels=np.array(list(m.measured)), input_channels=np.array(["F-X3"]))
    return path
