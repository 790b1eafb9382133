"""Build the repository's compact copies of the public recordings (run once; outputs committed).

    .venv/bin/python data/convert.py [--src ../shared/data] [--broad-only]

Reads the byte-for-byte copies in ``../shared/data/<name>/`` with :mod:`jaxcal.readers` and writes
``data/<name>/``:

* ``*.npz``: the conventions' recording (``t`` float64 s; raw counts as integers; physical values
  converted to g / rad/s and stored as float32, :func:`compact`), read with :func:`jaxcal.readers.read`
  and written by :func:`jaxcal.recording.save_recording` (the library's one recording writer).
* ``*_head.*``: the first lines of each original file, byte for byte, so that the reader tests
  exercise the real formats without the full files.
* small reference files (calibration results published next to the data) copied verbatim.
* ``README.md``: the upstream README (provenance, license, reference values) plus a note on
  what was converted.

The imu_tk ``.mat`` files are plain ASCII; the BROAD ``.mat`` files are MATLAB 5 binaries, read
with scipy (a jaxcal dependency), and their format excerpt ``*_head.mat`` is the first
``BROAD_HEAD`` samples of every variable re-written with ``scipy.io.savemat``. Nothing in tests or
experiments reads ``../shared`` at run time.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from jaxcal import readers  # noqa: E402
from jaxcal.recording import Recording, save_recording  # noqa: E402

HEAD_LINES = 400
BROAD_HEAD = 2000  # samples in the BROAD format excerpts (7 s: static start, first mocap gaps)
BROAD_TRIALS = ("07_undisturbed_fast_rotation_B", "21_undisturbed_fast_combined")
BROAD_LICENSE = "LICENSE_BROAD_CC-BY-4.0.txt"


KEEP_FLOAT64 = ("t", "gt_t")  # times keep float64 (microseconds over hours); other float arrays -> float32


def _float32(name: str, v):
    """``v`` as float32 if it is a float64 array of at least one dimension not in :data:`KEEP_FLOAT64`."""
    if isinstance(v, np.ndarray) and v.dtype == np.float64 and v.ndim > 0 and name not in KEEP_FLOAT64:
        return v.astype(np.float32)
    return v


def compact(rec: Recording) -> Recording:
    """The compact copy's precision: float64 arrays (fields and extras; not ``t`` / ``gt_t``, not
    scalars) as float32; counts, flags and scalars unchanged."""
    fields = {f.name: _float32(f.name, getattr(rec, f.name)) for f in dataclasses.fields(rec) if f.name != "extra"}
    return rec.replace(**fields, extra={k: _float32(k, v) for k, v in rec.extra.items()})


def write(rec: Recording, path: Path) -> None:
    """Write the compact copy of ``rec`` (:func:`compact`) with :func:`jaxcal.recording.save_recording`."""
    save_recording(compact(rec), path)


def head(src: Path, dst: Path, n: int = HEAD_LINES) -> None:
    with src.open("rb") as f:
        lines = [f.readline() for _ in range(n)]
    dst.write_bytes(b"".join(lines))


def readme(src_dir: Path, dst_dir: Path, note: str) -> None:
    text = (src_dir / "README.md").read_text()
    text += "\n\n## Compact copy in this repository (written by `data/convert.py`)\n" + note.strip() + "\n"
    (dst_dir / "README.md").write_text(text)


def main(src: Path) -> None:
    # imu_tk Xsens -----------------------------------------------------------------------
    s, d = src / "imu_tk_xsens_multipos", HERE / "imu_tk_xsens_multipos"
    d.mkdir(exist_ok=True)
    rec = readers.read("imu_tk", [s / "xsens_acc.mat", s / "xsens_gyro.mat"])
    write(rec, d / "xsens.npz")
    head(s / "xsens_acc.mat", d / "xsens_acc_head.txt")
    head(s / "xsens_gyro.mat", d / "xsens_gyro_head.txt")
    readme(s, d, f"""
- `xsens.npz`: the full recording ({rec.n} samples), `t` (s, float64), `acc` and `gyr` raw
  counts (int32), via `jaxcal.readers.read_imu_tk`.
- `xsens_acc_head.txt`, `xsens_gyro_head.txt`: the first {HEAD_LINES} lines of the two `.mat`
  (ASCII) files, byte for byte, for the reader tests.
""")

    # imucal -------------------------------------------------------------------------------
    s, d = src / "imucal_ferraris_example", HERE / "imucal_ferraris_example"
    d.mkdir(exist_ok=True)
    sess = readers.read("imucal", [s / "example_ferraris_session.csv", s / "example_ferraris_session_list.json"],
                        fs=102.4, acc_unit="m/s^2", gyr_unit="deg/s")
    write(sess, d / "session.npz")
    ann = readers.read("imucal", [s / "annotated_session.csv"], fs=204.8)
    write(ann, d / "annotated.npz")
    for f in ("example_cal.json", "example_ferraris_session_list.json"):
        shutil.copyfile(s / f, d / f)
    head(s / "example_ferraris_session.csv", d / "example_ferraris_session_head.csv")
    head(s / "annotated_session.csv", d / "annotated_session_head.csv")
    readme(s, d, f"""
- `session.npz`: `example_ferraris_session.csv` ({sess.n} samples) converted to g and rad/s
  (from m/s^2 with 9.80665 and deg/s), `t = n_samples / 102.4`; `section`/`section_names` from
  `example_ferraris_session_list.json` (-1 outside the sections). The physical values are the
  authors' nominal conversion, i.e. still uncalibrated.
- `annotated.npz`: `annotated_session.csv` ({ann.n} samples) as raw counts, re-ordered by
  sample index, `t = samples / 204.8`, `section` = index into `section_names`. The parts were cut
  out of a longer session: the motion between them is not in the file.
- `example_cal.json`, `example_ferraris_session_list.json`: verbatim copies.
- `*_head.csv`: the first {HEAD_LINES} lines of the two CSVs, byte for byte.
""")

    # MPU-6050 ------------------------------------------------------------------------------
    s, d = src / "tomisuarez_mpu6050", HERE / "tomisuarez_mpu6050"
    d.mkdir(exist_ok=True)
    names = {"example_data_calibration.csv": "calibration.npz", "example_data_tinit_calc.csv": "tinit_calc.npz",
             "imu_static_test.csv": "static_test.npz", "imu_90_x_rot.csv": "rot90x.npz"}
    for f, out in names.items():
        r = readers.read("mpu6050", [s / f])
        write(r.replace(acc=r.acc.astype("int16"), gyr=r.gyr.astype("int16")), d / out)
    head(s / "example_data_calibration.csv", d / "example_data_calibration_head.csv")
    (d / "optimization_result_data").mkdir(exist_ok=True)
    for f in (s / "optimization_result_data").iterdir():
        shutil.copyfile(f, d / "optimization_result_data" / f.name)
    readme(s, d, f"""
- `calibration.npz`, `tinit_calc.npz`, `static_test.npz`, `rot90x.npz`: the four recordings in
  full, raw counts as int16, `t = n / Fs`, datasheet scales `acc_lsb_per_g` = 16384 and
  `gyr_lsb_per_rads` = 131 * 180 / pi, the other metadata lines as `meta_*`.
- `optimization_result_data/`: verbatim copies of the repository's calibration results.
- `example_data_calibration_head.csv`: the first {HEAD_LINES} lines, byte for byte.
""")

    # TUM-VI -------------------------------------------------------------------------------
    s, d = src / "tumvi_room1_512_16", HERE / "tumvi_room1_512_16"
    d.mkdir(exist_ok=True)
    r = readers.read("tumvi", [s / "dataset-room1_512_16.csv", s / "dataset-room1_512_16_gt.csv"])
    write(r, d / "room1.npz")
    head(s / "dataset-room1_512_16.csv", d / "imu_head.csv")
    head(s / "dataset-room1_512_16_gt.csv", d / "gt_head.csv")
    readme(s, d, f"""
- `room1.npz`: IMU ({r.n} samples) in g (m/s^2 / 9.80665) and rad/s, float32; `t` in s from
  the first IMU sample (`t0` = its Unix time); motion capture interpolated to the IMU times as
  `pos_ref` (m) and `quat_ref` (**scalar first**, re-ordered from the ROS x, y, z, w; slerp; held at the
  ends; `ref_valid` False outside the track and across mocap gaps over 50 ms), and the original 120 Hz track as `gt_t`, `gt_pos`, `gt_quat`.
- `imu_head.csv`, `gt_head.csv`: the first {HEAD_LINES} lines of the two CSVs, byte for byte.
""")

    # x-io Fusion --------------------------------------------------------------------------
    s, d = src / "xio_fusion_sensor_data", HERE / "xio_fusion_sensor_data"
    d.mkdir(exist_ok=True)
    r = readers.read("fusion", [s / "sensor_data.csv"])
    write(r, d / "sensor_data.npz")
    head(s / "sensor_data.csv", d / "sensor_data_head.csv")
    readme(s, d, f"""
- `sensor_data.npz`: the full recording ({r.n} samples), `t` (s, uneven, as recorded),
  `acc` (g), `gyr` (rad/s, from deg/s), `mag` (uT), float32.
- `sensor_data_head.csv`: the first {HEAD_LINES} lines, byte for byte.
""")

    # BROAD ---------------------------------------------------------------------------------
    main_broad(src)


def main_broad(src: Path) -> None:
    """Only the BROAD folders (``--broad-only``): ``data/broad_<trial>/``."""
    for trial in BROAD_TRIALS:
        broad(src / f"broad_{trial}", HERE / f"broad_{trial}", trial)


def broad(s: Path, d: Path, trial: str) -> None:
    """One BROAD trial: ``<trial>.npz`` (jaxcal recording, float32), ``<trial>_head.mat``, license, README."""
    import scipy.io

    d.mkdir(exist_ok=True)
    r = readers.read("broad", [s / f"{trial}.mat"])
    write(r, d / f"{trial}.npz")
    m = scipy.io.loadmat(s / f"{trial}.mat")
    head_vars = {k: (v[:BROAD_HEAD] if np.ndim(v) == 2 and v.shape[0] == r.n else v)
                 for k, v in m.items() if not k.startswith("__")}
    scipy.io.savemat(d / f"{trial}_head.mat", head_vars, do_compression=True, oned_as="column")
    shutil.copyfile(s / BROAD_LICENSE, d / BROAD_LICENSE)
    ok = r.ref_valid

    def gap_rows(a: np.ndarray) -> int:
        return int(np.isnan(a).any(axis=1).sum())

    readme(s, d, f"""
- **Attribution (CC BY 4.0):** data from D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD—A
  Benchmark for Robust Inertial Orientation Estimation", *Data* 6(7):72, 2021,
  doi:10.3390/data6070072 (https://github.com/dlaidig/broad, file `data_mat/{trial}.mat`, commit
  `7e2f8189bb4a3ac91eae32c69b6bc87f08a6e2ad`). Changed here: file format and units (below); no
  values were cropped, filled or re-synchronised. License text: `{BROAD_LICENSE}` (verbatim copy).
- `{trial}.npz`: the full trial ({r.n} samples, {r.n / r.fs:.1f} s) as a jaxcal recording
  (`jaxcal.readers.read_broad`, then `jaxcal.recording.save_recording`, `savez_compressed`):
  `t = k / sampling_rate` (s, float64; `fs` = {r.fs:.6f} Hz); `acc` in g (`imu_acc` m/s^2 / 9.80665),
  `gyr` rad/s (`imu_gyr`), `mag` uT (`imu_mag`), `pos_ref` m (`opt_pos`), `quat_ref` Hamilton
  `[w, x, y, z]` IMU frame -> ENU = body to world (`opt_quat`, order and direction unchanged,
  finite rows renormalised), all float32. Mocap gaps stay NaN (whole rows; `pos_ref` NaN in
  {gap_rows(r.pos_ref)} rows, `quat_ref` NaN in {gap_rows(r.quat_ref)} rows);
  `ref_valid` (bool) is True where both are finite ({int(ok.sum())} of {ok.size} rows).
  Extras: `movement` (bool, the file's movement-phase flag), `meta_info` (the `info` text).
- `{trial}_head.mat`: the first {BROAD_HEAD} samples of every variable of the original `.mat`
  (same names, shapes and dtypes; `sampling_rate` and `info` whole), re-written with
  `scipy.io.savemat` (MATLAB 5, compressed) as a format excerpt for the reader tests. Not byte
  for byte: a MAT file cannot be cut.
- Rebuild: `.venv/bin/python data/convert.py --broad-only` (without the flag it rewrites every folder of `data/`).
""")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, default=HERE.parent.parent / "shared" / "data")
    ap.add_argument("--broad-only", action="store_true", help="rebuild only the BROAD folders")
    args = ap.parse_args()
    (main_broad if args.broad_only else main)(args.src)
