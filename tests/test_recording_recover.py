"""Recovery of unfinished recordings: truncation at many offsets and a SIGKILLed writer."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from fnsi_lab.daq.recording import (NotMcapError, RecordingError, RecordingNotFoundError, open_recording,
                           recover, topics)


def _chunk_ends(path: Path) -> list[tuple[int, int]]:
    """(byte offset just past each chunk record, messages in all chunks so far)."""
    ends = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        total = 0
        for ci in sorted(reader.get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset):
            f.seek(ci.chunk_start_offset)
            chunk = next(StreamReader(f, skip_magic=True, emit_chunks=True).records)
            from mcap.stream_reader import breakup_chunk
            from mcap.records import Message
            total += sum(isinstance(r, Message) for r in breakup_chunk(chunk))
            ends.append((ci.chunk_start_offset + ci.chunk_length, total))
    return ends


def test_recover_complete_file_is_identical(write_recording, tmp_path):
    path, blocks = write_recording(attachments=[("a.bin", "application/octet-stream", b"\0\1")])
    report = recover(path, tmp_path / "copy.mcap")
    assert report.complete and report.messages == len(blocks) and report.attachments == 1
    with open(path, "rb") as f:
        assert report.metadata == len(list(make_reader(f).iter_metadata()))
    with open_recording(path) as a, open_recording(tmp_path / "copy.mcap") as b:
        assert a.metadata == b.metadata and a.channels == b.channels
        assert a.attachments() == b.attachments()
        for x, y in zip(a.iter_blocks(), b.iter_blocks(), strict=True):
            assert x.data.tobytes() == y.data.tobytes() and x.t0_ns == y.t0_ns
    assert "input was complete" in report.summary()


def test_recover_truncated_at_many_offsets(write_recording, tmp_path):
    path, blocks = write_recording(n_periods=10, chunk_size=3_000, noise=1e-3,
                                   attachments=[("experiment.yaml", "application/yaml", b"a: 1\n")])
    data = path.read_bytes()
    ends = _chunk_ends(path)
    assert len(ends) >= 8
    first_chunk_start = ends[0][0] - 1  # any cut before the first chunk end keeps no message
    rng = np.random.default_rng(1)
    cuts = sorted({*(e for e, _ in ends), *(e - 1 for e, _ in ends), *(e + 5 for e, _ in ends),
                   *rng.integers(first_chunk_start, ends[-1][0], 20).tolist()})
    out = tmp_path / "out.mcap"
    broken = tmp_path / "broken.mcap"
    with open(path, "rb") as f:
        n_metadata = len(list(make_reader(f).iter_metadata()))
    for cut in cuts:
        broken.write_bytes(data[:cut])
        report = recover(broken, out)
        expected = max((n for end, n in ends if end <= cut), default=0)
        assert report.messages == expected, f"cut at {cut}"
        assert not report.complete and report.bytes_recovered <= cut
        assert report.attachments == 1 and report.metadata == n_metadata
        if expected == 0:
            continue
        with open_recording(out) as rec:
            got = list(rec.iter_blocks())
            assert rec.metadata["recovery"]["bytes_recovered"] == report.bytes_recovered
            assert rec.attachments()["experiment.yaml"] == b"a: 1\n"
        assert len(got) == expected
        for a, b in zip(got, blocks):
            assert a.data.tobytes() == b.data.tobytes()
            assert (a.t0_ns, a.sequence, a.first_sample) == (b.t0_ns, b.sequence, b.first_sample)
    # a cut inside the summary keeps everything
    broken.write_bytes(data[:-20])
    assert recover(broken, out).messages == len(blocks)


def test_recover_skips_a_corrupt_chunk_and_keeps_the_rest(write_recording, tmp_path):
    path, blocks = write_recording(n_periods=10, chunk_size=3_000)
    data = bytearray(path.read_bytes())
    ends = _chunk_ends(path)
    # flip a byte in the middle of the 4th chunk's compressed data: CRC or zstd fails
    start4, end4 = ends[2][0], ends[3][0]
    data[(start4 + end4) // 2 + 20] ^= 0xFF
    broken = tmp_path / "corrupt.mcap"
    broken.write_bytes(bytes(data[:-200]))
    report = recover(broken, tmp_path / "out.mcap")
    in_4th = ends[3][1] - ends[2][1]
    assert report.messages == ends[-1][1] - in_4th  # every chunk but the damaged one
    ((a, b, why),) = report.damaged  # the 4th chunk record, exactly
    assert start4 < a < end4 and b == end4 and "chunk" in why
    assert report.bytes_skipped == b - a
    assert report.seconds_skipped == pytest.approx(in_4th * blocks[0].n_samples / 1000.0)


def test_recover_bad_inputs(tmp_path, write_recording):
    with pytest.raises(RecordingNotFoundError):
        recover(tmp_path / "missing.mcap", tmp_path / "o.mcap")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not mcap" * 10)
    with pytest.raises(NotMcapError):
        recover(junk, tmp_path / "o.mcap")
    path, _ = write_recording()
    with pytest.raises(RecordingError, match="different output"):
        recover(path, path)


WRITER_SCRIPT = textwrap.dedent("""
    import sys, time
    import numpy as np
    from fnsi_lab.daq.block import Block
    from fnsi_lab.daq.channels import ChannelInfo
    from fnsi_lab.daq.recording import Recorder

    chans = (ChannelInfo("F", "force"), ChannelInfo("X1"), ChannelInfo("X2"), ChannelInfo("X3"))
    rec = Recorder(sys.argv[1], chans, 1000.0, flush_interval_s=0.2,
                   attachments=[("experiment.yaml", "application/yaml", b"name: kill\\n")])
    print("started", flush=True)
    i = 0
    while True:
        data = np.random.default_rng(i).standard_normal((50, 4)).astype(np.float32)
        rec.write_block(Block(data, chans, 1000.0, i, 50 * i, 50_000_000 * i))
        i += 1
        if rec.blocks_flushed and rec.blocks_flushed != getattr(rec, "_reported", 0):
            rec._reported = rec.blocks_flushed
            print("flushed", rec.blocks_flushed, flush=True)
        time.sleep(0.002)
""")


def test_recover_after_sigkill(tmp_path):
    """A writer killed with SIGKILL loses at most what arrived after its last flush."""
    script = tmp_path / "writer.py"
    script.write_text(WRITER_SCRIPT)
    path = tmp_path / "killed.mcap"
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen([sys.executable, str(script), str(path)], stdout=subprocess.PIPE,
                            text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "started"
        time.sleep(1.0)
    finally:
        proc.kill()  # SIGKILL: no handler, no finish()
        out, _ = proc.communicate(timeout=30)
    flushed = [int(line.split()[1]) for line in out.splitlines() if line.startswith("flushed")]
    assert proc.returncode == -9 and flushed, out
    with pytest.raises(RecordingError, match="recover"):
        open_recording(path)
    report = recover(path, tmp_path / "fixed.mcap")
    assert not report.complete
    assert report.messages >= flushed[-1] >= 3
    with open_recording(tmp_path / "fixed.mcap") as rec:
        assert rec.attachments()["experiment.yaml"] == b"name: kill\n"
        got = list(rec.iter_blocks())
    assert len(got) == report.messages_by_topic[topics.TOPIC_SAMPLES]
    for i, b in enumerate(got):
        expected = np.random.default_rng(i).standard_normal((50, 4)).astype(np.float32)
        assert b.sequence == i and b.t0_ns == 50_000_000 * i
        assert b.data.tobytes() == expected.tobytes()
