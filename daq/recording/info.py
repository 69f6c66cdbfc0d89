"""``fnsi-lab info``: what a recording holds, as a JSON-able dict and as text."""

from __future__ import annotations

import os
from collections import Counter
from typing import Any

from fnsi_lab.daq.recording import schema, topics
from fnsi_lab.daq.recording.reader import open_recording


def recording_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Describe a recording.

    Reads the summary, the metadata and the sample message headers (the float data are
    decompressed but not converted).

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.

    Returns
    -------
    dict
        JSON-able: ``file``, ``size_bytes``, ``channels`` [{name, unit, quantity}],
        ``n_inputs``, ``n_outputs``, ``sample_rate_hz``, ``samples`` (per channel),
        ``duration_s``, ``realizations``, ``samples_per_period``, ``periods`` (whole
        periods per realization), ``periods_declared``, ``transient_periods``,
        ``messages`` (all topics), ``blocks``, ``lost_blocks`` (gaps in the block
        sequence), ``topics`` {topic: count}, ``chunks``, ``events`` {kind: count},
        ``excitation``, ``experiment``, ``truth``, ``source``, ``attachments``
        [{name, media_type, size}], ``metadata_keys``, ``software_version``, ``library``,
        ``trigger`` (software trigger settings or None), ``clock_check``
        (:meth:`daq.periodicity.ClockCheck.to_dict`, None without periods), ``notes``
        (what could not be checked: a file another writer made without CRCs).

    Raises
    ------
    RecordingError
        As :func:`~daq.recording.reader.open_recording`; with CRC checks on (the default),
        :class:`DamagedRecordingError` naming the first damaged chunk or attachment.
    """
    with open_recording(path) as rec:
        if rec.validate_crcs:  # every chunk and attachment, not only those read below
            problems = rec.damage()
            if problems:
                more = f" (and {len(problems) - 1} more damaged parts)" if len(problems) > 1 else ""
                raise rec.damaged_error(problems[0] + more)
        per_real: Counter[int] = Counter()
        total = 0
        lost = 0
        last_seq: int | None = None
        for _, payload in rec._iter_samples():
            try:
                n_samples, _, _, realization, sequence = schema.decode_header(payload)
            except schema.MalformedMessageError as exc:
                raise rec.damaged_error(f"corrupt sample message ({exc})") from None
            per_real[realization] += n_samples
            total += n_samples
            if last_seq is not None and sequence > last_seq + 1:
                lost += sequence - last_seq - 1
            last_seq = sequence
        events = Counter(e.get("kind", "?") for e in rec.iter_events())
        exc = rec.excitation
        n = int(exc["samples_per_period"]) if exc and exc.get("samples_per_period") else None
        stats = rec.summary.statistics
        header = rec._reader.get_header()
        fs = rec.sample_rate_hz
        info: dict[str, Any] = {
            "file": str(rec.path),
            "size_bytes": os.path.getsize(rec.path),
            "channels": [{"name": c.name, "unit": c.unit, "quantity": c.quantity}
                         for c in rec.channels],
            "n_inputs": len(rec.input_channels),
            "n_outputs": len(rec.output_channels),
            "sample_rate_hz": fs,
            "samples": total,
            "duration_s": total / fs if fs else 0.0,
            "realizations": len(per_real),
            "samples_per_period": n,
            "periods": (min(per_real.values()) // n) if (n and per_real) else None,
            "periods_declared": exc.get("periods") if exc else None,
            "transient_periods": exc.get("transient_periods") if exc else None,
            "messages": int(stats.message_count) if stats else None,
            "blocks": rec.n_blocks,
            "lost_blocks": lost,
            "topics": rec.message_counts,
            "chunks": len(rec.summary.chunk_indexes),
            "events": dict(sorted(events.items())),
            "excitation": exc,
            "experiment": rec.experiment,
            "truth": rec.truth,
            "source": rec.metadata.get(topics.META_SOURCE),
            "attachments": rec.attachment_info(),
            "metadata_keys": sorted(rec.metadata),
            "software_version": rec.experiment.get(topics.SOFTWARE_VERSION_KEY),
            "library": header.library,
            "trigger": rec.metadata.get("trigger"),
            "clock_check": _clock_check(rec) if n else None,
        }
        info["notes"] = list(rec.notes)  # what could not be checked (no CRCs)
    return info


def _clock_check(rec: Any) -> dict[str, Any] | None:
    """Drive vs acquisition clock (daq.periodicity); None when periods cannot be cut."""
    from fnsi_lab.daq.periodicity import check_record_clock
    from fnsi_lab.daq.recording.errors import RecordingError

    try:
        return check_record_clock(rec.read_periodic()).to_dict()
    except RecordingError:  # lost blocks, shorter than a period: reported elsewhere
        return None


def _fmt_bytes(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024  # type: ignore[assignment]
    return f"{n} B"


def format_info(info: dict[str, Any]) -> str:
    """Human-readable text of :func:`recording_info`'s dict (what ``fnsi-lab info`` prints)."""
    lines = [f"{info['file']}  ({_fmt_bytes(info['size_bytes'])}, written by {info.get('library', '?')})"]
    exp = info.get("experiment") or {}
    if exp.get("name") or exp.get("source_kind") or exp.get("source"):
        lines.append(f"experiment: {exp.get('name') or '?'}"
                     + (f", source {exp.get('source_kind') or exp.get('source')}" if
                        (exp.get('source_kind') or exp.get('source')) else ""))
    lines.append(f"data: {info['samples']} samples x {len(info['channels'])} channels @ "
                 f"{info['sample_rate_hz']:g} Hz = {info['duration_s']:.3f} s, "
                 f"{info['blocks']} blocks, {info['chunks']} chunks"
                 + (f", {info['lost_blocks']} LOST blocks" if info.get("lost_blocks") else ""))
    if info.get("samples_per_period"):
        declared, transient = info.get("periods_declared"), info.get("transient_periods")
        said = ", ".join([f"declared {declared}" if declared is not None
                          else "number not declared",
                          f"{transient} transient" if transient is not None
                          else "transient not declared"])
        lines.append(f"periodic: N = {info['samples_per_period']}, {info['periods']} whole "
                     f"periods per realization ({said}), {info['realizations']} realization(s)")
    exc = info.get("excitation")
    if exc:
        band = exc.get("band_hz")
        # the multisine's RMS is in the force channels' unit (the recording's channel table)
        force_unit = next((c["unit"] for c in info["channels"] if c["quantity"] == "force"
                           and c.get("unit")), "")
        lines.append(f"excitation: {exc.get('kind', '?')}"
                     + (f" {band[0]:g}-{band[1]:g} Hz" if band else "")
                     + (f", rms {exc['rms']:g} {force_unit}".rstrip()
                        if exc.get("rms") is not None else "")
                     + (f", phases {exc['phases']}" if exc.get("phases") else "")
                     + (f", seed {exc['seed']}" if "seed" in exc else ""))
        drive = exc.get("drive")
        if drive:
            lines.append(f"drive: {drive.get('file', {}).get('name', '?')}, "
                         f"{len(drive.get('excited_lines', []))} lines, unit "
                         f"{drive.get('scaling', {}).get('unit')}, sha256 "
                         f"{str(drive.get('signal_sha256'))[:12]}...")
    trig = info.get("trigger")
    if trig:
        lines.append(f"trigger: {trig['channel']} {trig['slope']} through {trig['level']:g}, "
                     f"{trig['pre_samples']} pre-trigger samples")
    if info.get("clock_check"):
        lines.append(info["clock_check"]["message"])
    lines.append(f"channels ({info['n_inputs']} inputs, {info['n_outputs']} outputs):")
    for c in info["channels"]:
        role = "in " if c["quantity"] == "force" else "out"
        lines.append(f"  {role} {c['name']:<20} {c['quantity']:<13} [{c['unit']}]")
    if info.get("events"):
        lines.append("events: " + ", ".join(f"{k} x{v}" for k, v in info["events"].items()))
    aux = {t: n for t, n in (info.get("topics") or {}).items()
           if t not in (topics.TOPIC_SAMPLES, topics.TOPIC_EVENTS)}
    if aux:
        lines.append("other topics: " + ", ".join(f"{t} ({n})" for t, n in aux.items()))
    if info.get("attachments"):
        lines.append("attachments: " + ", ".join(
            f"{a['name']} ({a['media_type']}, {_fmt_bytes(a['size'])})" for a in info["attachments"]))
    if info.get("truth") is not None:
        truth = info["truth"]
        keys = ", ".join(sorted(truth)) if isinstance(truth, dict) else type(truth).__name__
        lines.append(f"truth: {keys}")
    lines.append(f"metadata: {', '.join(info.get('metadata_keys') or []) or 'none'}")
    lines.append(f"fnsi-lab version: {info.get('software_version') or 'not recorded'}")
    lines += [f"note: {note}" for note in info.get("notes") or ()]
    return "\n".join(lines)
