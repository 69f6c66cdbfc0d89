"""Lab file formats (issue 17): import speed per format and export precision at SmallSat size.

1. A SmallSat-sized record (1 force + 39 responses, 6 periods of 8192 samples at 1 kHz,
   float32) is written as TDMS (npTDMS), UFF 58 ASCII (pyuff) and CSV, then imported
   (read + plan + MCAP recording); times are reported with the ratio to the record's
   duration.
2. The simulated SmallSat test is recorded, identified (robust pipeline), exported to UFF
   and read back with pyuff: worst frequency and damping errors over all modes, and the
   export time.

Usage: python bench/bench_formats.py [--out bench/out/formats.json]
"""

from __future__ import annotations

import argparse
import csv
import math
import tempfile
import time
from pathlib import Path

import numpy as np


def _write_inputs(d: Path, data: np.ndarray, names: list[str], units: list[str], fs: float
                  ) -> dict[str, Path]:
    import pyuff
    from nptdms import ChannelObject, GroupObject, RootObject, TdmsWriter

    files = {"tdms": d / "rec.tdms", "uff": d / "rec.uff", "csv": d / "rec.csv"}
    with TdmsWriter(str(files["tdms"])) as w:
        w.write_segment([RootObject({}), GroupObject("g")] + [
            ChannelObject("g", n, data[:, j], properties={"unit_string": u,
                                                          "wf_increment": 1 / fs})
            for j, (n, u) in enumerate(zip(names, units))])
    sets = [pyuff.prepare_58(func_type=1, id1=n, rsp_node=j + 1, rsp_dir=3, ref_node=0,
                             ref_dir=0, data=data[:, j].astype(float),
                             x=np.arange(data.shape[0]) / fs, abscissa_spacing=1,
                             abscissa_spec_data_type=17,
                             ordinate_spec_data_type=13 if u == "N" else 8,
                             ordinate_axis_units_lab=u, orddenom_spec_data_type=0,
                             z_axis_spec_data_type=0)
            for j, (n, u) in enumerate(zip(names, units))]
    pyuff.UFF(str(files["uff"])).write_sets(sets, mode="overwrite")
    with open(files["csv"], "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow([f"{n} [{u}]" for n, u in zip(names, units)])
        wr.writerows(data.tolist())
    return files


def bench_import(d: Path) -> dict:
    from fnsi_lab.daq.formats import plan_import, read_lab_file, write_recording

    fs, n_per, periods = 1000.0, 8192, 6
    rng = np.random.default_rng(0)
    period = rng.standard_normal((n_per, 40)).astype(np.float32)
    data = np.tile(period, (periods, 1))
    names = ["F-in"] + [f"N{k}-Z" for k in range(39)]
    units = ["N"] + ["mm"] * 39
    files = _write_inputs(d, data, names, units, fs)
    duration = data.shape[0] / fs
    out = {"samples": data.shape[0], "channels": data.shape[1], "duration_s": duration}
    for kind, path in files.items():
        t0 = time.perf_counter()
        table = read_lab_file(path)
        t1 = time.perf_counter()
        plan = plan_import(table, samples_per_period=n_per, sample_rate_hz=fs)
        write_recording(table, plan, d / f"{kind}.mcap")
        t2 = time.perf_counter()
        out[kind] = {"file_mb": path.stat().st_size / 1e6, "read_s": t1 - t0,
                     "record_s": t2 - t1, "times_real_time": duration / (t2 - t0)}
        print(f"{kind:5s} {out[kind]['file_mb']:7.1f} MB  read {t1 - t0:6.2f} s  record "
              f"{t2 - t1:5.2f} s  = {duration / (t2 - t0):6.1f}x real time")
    return out


def bench_export(d: Path) -> dict:
    import pyuff

    import fnsi_lab
    from fnsi_lab.export import assign_dofs, result_from_dict, uff_text

    rec = d / "smallsat.mcap"
    fnsi_lab.acquire(out=rec)
    ident = fnsi_lab.identify(str(rec), "smallsat39")
    res = result_from_dict(ident.to_json(), "smallsat")
    t0 = time.perf_counter()
    out_dofs, in_dofs = assign_dofs(res.outputs, res.inputs)
    text, _ = uff_text(res, out_dofs, in_dofs)
    (d / "smallsat.uff").write_text(text)
    t1 = time.perf_counter()
    sets = pyuff.UFF(str(d / "smallsat.uff")).read_sets()
    t2 = time.perf_counter()
    modes = [s for s in sets if s["type"] == 55]
    f_err = z_err = z_rel = 0.0
    for s, f, z in zip(modes, res.frequency_hz, res.damping_ratio):
        lam = s["eig"]
        f_err = max(f_err, abs(abs(lam) / (2 * math.pi) - f) / f)
        z_err = max(z_err, abs(-lam.real / abs(lam) - z))
        z_rel = max(z_rel, abs(-lam.real / abs(lam) - z) / abs(z))
    # the same modes through pyuff's own dataset-55 writer (E13.5 fields), for comparison
    from fnsi_lab.export.uff import eigenvalue, node_vectors
    ref_sets = []
    for k, (f, z, shape) in enumerate(zip(res.frequency_hz, res.damping_ratio, res.shapes)):
        vec, _ = node_vectors(shape, out_dofs)
        nodes = sorted(vec)
        ref_sets.append(pyuff.prepare_55(
            model_type=1, analysis_type=3, data_ch=2, spec_data_type=8, data_type=5,
            n_data_per_node=3, load_case=1, mode_n=k + 1, eig=eigenvalue(f, z),
            modal_a=0j, modal_b=0j, node_nums=np.array(nodes),
            r1=np.array([vec[n][0] for n in nodes]), r2=np.array([vec[n][1] for n in nodes]),
            r3=np.array([vec[n][2] for n in nodes])))
    pyuff.UFF(str(d / "pyuff55.uff")).write_sets(ref_sets, mode="overwrite")
    f_ref = z_ref = 0.0
    for s, f, z in zip(pyuff.UFF(str(d / "pyuff55.uff")).read_sets(), res.frequency_hz,
                       res.damping_ratio):
        lam = s["eig"]
        f_ref = max(f_ref, abs(abs(lam) / (2 * math.pi) - f) / f)
        z_ref = max(z_ref, abs(-lam.real / abs(lam) - z))
    n58 = sum(1 for s in sets if s["type"] == 58)
    print(f"SmallSat export: {len(modes)} modes, {n58} FRFs, {len(text) / 1e6:.1f} MB in "
          f"{t1 - t0:.2f} s (pyuff reads it back in {t2 - t1:.2f} s)")
    print(f"  worst frequency error {f_err:.2g} (relative), damping {z_err:.2g} (absolute), "
          f"{z_rel:.2g} (relative)")
    print(f"  pyuff's own writer (E13.5): frequency {f_ref:.2g}, damping {z_ref:.2g}")
    return {"pyuff_writer_max_frequency_rel_error": f_ref,
            "pyuff_writer_max_damping_abs_error": z_ref,"modes": len(modes), "frfs": n58, "uff_mb": len(text) / 1e6,
            "export_s": t1 - t0, "pyuff_read_s": t2 - t1,
            "max_frequency_rel_error": f_err, "max_damping_abs_error": z_err,
            "max_damping_rel_error": z_rel}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=None, help="write the numbers as JSON")
    args = parser.parse_args()
    from fnsi_lab.blas import limit_blas_threads

    limit_blas_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        results = {"import": bench_import(d), "export": bench_export(d)}
    if args.out:
        from fnsi_lab.outputs import write_json

        write_json(results, args.out)


if __name__ == "__main__":
    main()
