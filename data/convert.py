"""Build the repository's compact copies of the public recordings (run once; outputs committed).

    .venv/bin/python data/convert.py [--src ../shared/data]

Reads the byte-for-byte copies in ``../shared/data/<name>/`` with :mod:`jaxcal.readers` and writes
``data/<name>/``:

* ``*.npz``: the conventions' recording (``t`` float64 s; raw counts as integers; physical values
  converted to g / rad/s and stored as float32), written by :func:`jaxcal.readers.save_npz`.
* ``*_head.*``: the first lines of each original file, byte for byte, so that the reader tests
  exercise the real formats without the full files.
* small reference files (calibration results published next to the data) copied verbatim.
* ``README.md``: the upstream README (provenance, license, reference values) plus a note on
  what was converted.

No scipy is needed: the imu_tk ``.mat`` files are plain ASCII. Nothing in tests or experiments
reads ``../shared`` at run time.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from jaxcal import readers  # noqa: E402

HEAD_LINES = 400


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
    rec = readers.read_dict("imu_tk", [s / "xsens_acc.mat", s / "xsens_gyro.mat"])
    readers.save_npz(rec, d / "xsens.npz")
    head(s / "xsens_acc.mat", d / "xsens_acc_head.txt")
    head(s / "xsens_gyro.mat", d / "xsens_gyro_head.txt")
    readme(s, d, f"""
- `xsens.npz`: the full recording ({len(rec['t'])} samples), `t` (s, float64), `acc` and `gyr` raw
  counts (int32), via `jaxcal.readers.read_imu_tk`.
- `xsens_acc_head.txt`, `xsens_gyro_head.txt`: the first {HEAD_LINES} lines of the two `.mat`
  (ASCII) files, byte for byte, for the reader tests.
""")

    # imucal -------------------------------------------------------------------------------
    s, d = src / "imucal_ferraris_example", HERE / "imucal_ferraris_example"
    d.mkdir(exist_ok=True)
    sess = readers.read_dict("imucal", [s / "example_ferraris_session.csv", s / "example_ferraris_session_list.json"],
                        fs=102.4, acc_unit="m/s^2", gyr_unit="deg/s")
    readers.save_npz(sess, d / "session.npz")
    ann = readers.read_dict("imucal", [s / "annotated_session.csv"], fs=204.8)
    readers.save_npz(ann, d / "annotated.npz")
    for f in ("example_cal.json", "example_ferraris_session_list.json"):
        shutil.copyfile(s / f, d / f)
    head(s / "example_ferraris_session.csv", d / "example_ferraris_session_head.csv")
    head(s / "annotated_session.csv", d / "annotated_session_head.csv")
    readme(s, d, f"""
- `session.npz`: `example_ferraris_session.csv` ({len(sess['t'])} samples) converted to g and rad/s
  (from m/s^2 with 9.80665 and deg/s), `t = n_samples / 102.4`; `section`/`section_names` from
  `example_ferraris_session_list.json` (-1 outside the sections). The physical values are the
  authors' nominal conversion, i.e. still uncalibrated.
- `annotated.npz`: `annotated_session.csv` ({len(ann['t'])} samples) as raw counts, re-ordered by
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
        r = readers.read_dict("mpu6050", [s / f])
        r["acc"], r["gyr"] = r["acc"].astype("int16"), r["gyr"].astype("int16")
        readers.save_npz(r, d / out)
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
    r = readers.read_dict("tumvi", [s / "dataset-room1_512_16.csv", s / "dataset-room1_512_16_gt.csv"])
    readers.save_npz(r, d / "room1.npz")
    head(s / "dataset-room1_512_16.csv", d / "imu_head.csv")
    head(s / "dataset-room1_512_16_gt.csv", d / "gt_head.csv")
    readme(s, d, f"""
- `room1.npz`: IMU ({len(r['t'])} samples) in g (m/s^2 / 9.80665) and rad/s, float32; `t` in s from
  the first IMU sample (`t0` = its Unix time); motion capture interpolated to the IMU times as
  `pos_ref` (m) and `quat_ref` (**scalar first**, re-ordered from the ROS x, y, z, w; slerp; held at the
  ends; `ref_valid` False outside the track and across mocap gaps over 50 ms), and the original 120 Hz track as `gt_t`, `gt_pos`, `gt_quat`.
- `imu_head.csv`, `gt_head.csv`: the first {HEAD_LINES} lines of the two CSVs, byte for byte.
""")

    # x-io Fusion --------------------------------------------------------------------------
    s, d = src / "xio_fusion_sensor_data", HERE / "xio_fusion_sensor_data"
    d.mkdir(exist_ok=True)
    r = readers.read_dict("fusion", [s / "sensor_data.csv"])
    readers.save_npz(r, d / "sensor_data.npz")
    head(s / "sensor_data.csv", d / "sensor_data_head.csv")
    readme(s, d, f"""
- `sensor_data.npz`: the full recording ({len(r['t'])} samples), `t` (s, uneven, as recorded),
  `acc` (g), `gyr` (rad/s, from deg/s), `mag` (uT), float32.
- `sensor_data_head.csv`: the first {HEAD_LINES} lines, byte for byte.
""")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--src", type=Path, default=HERE.parent.parent / "shared" / "data")
    main(ap.parse_args().src)
