"""Synthetic-lab speed and accuracy: CPU and wall time per preset, depth-on-surface error, occlusion achieved.

For each requested preset, generates sessions (noise on, heavy occlusion) and prints CPU time
(process time of this single-threaded process) and wall time; then the geometric check at 640x480
with noise off (masked depth back-projected with K and T_world_camera, distance to the true mesh at
the true pose, a few frames). Prints the figures; never fails on time.

    python benchmarks/synth_lab.py                 # tiny and full, one session each
    python benchmarks/synth_lab.py --presets tiny --objects all --interactions all
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from service.synth import INTERACTIONS, OBJECT_KINDS, SynthSpec, make_session  # noqa: E402


def surface_error(root: Path, frames) -> np.ndarray:
    import cv2
    import trimesh

    from service.synth.camera import backproject
    from service.transforms import xyzquat_to_pose

    s = json.loads((root / "session.json").read_text())
    K = np.asarray(s["camera"]["K"])
    X_WC = np.asarray(s["camera"]["T_world_camera"])
    mesh = trimesh.load(root / "ground_truth" / "mesh.obj", force="mesh")
    poses = np.loadtxt(root / "ground_truth" / "poses.csv", delimiter=",", skiprows=1)
    out = []
    for i in frames:
        z = cv2.imread(str(root / "depth" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED).astype(float) * s["camera"]["depth_scale"]
        m = cv2.imread(str(root / "masks" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED) > 0
        p_W = backproject(z, K, m) @ X_WC[:3, :3].T + X_WC[:3, 3]
        X = xyzquat_to_pose(poses[i, 1:8])
        out.append(np.abs(trimesh.proximity.signed_distance(mesh, (p_W - X[:3, 3]) @ X[:3, :3])))
    return np.concatenate(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--presets", default="tiny,full")
    ap.add_argument("--objects", default="oat_carton", help="comma list or 'all'")
    ap.add_argument("--interactions", default="push", help="comma list or 'all'")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--occlusion", default="heavy")
    ap.add_argument("--no-geometry", action="store_true")
    a = ap.parse_args(argv)
    cmd = "python benchmarks/synth_lab.py " + " ".join(shlex.quote(x) for x in (argv if argv is not None else sys.argv[1:]))
    objects = OBJECT_KINDS if a.objects == "all" else tuple(a.objects.split(","))
    inters = INTERACTIONS if a.interactions == "all" else tuple(a.interactions.split(","))
    print(f"# {cmd}")
    print("preset  object       interaction  frames  size     cpu_s   wall_s  hidden_mean  in_band_40_70  travel_m  rot_rad  contacts")
    with tempfile.TemporaryDirectory(prefix="vysics-bench-synth-") as tmp:
        for preset in a.presets.split(","):
            for obj in objects:
                for inter in inters:
                    spec = SynthSpec(object=obj, interaction=inter, seed=a.seed, preset=preset, occlusion=a.occlusion, noise=True)
                    c0, w0 = time.process_time(), time.perf_counter()
                    r = make_session(spec, Path(tmp) / f"{preset}_{spec.session_name()}")
                    cpu, wall = time.process_time() - c0, time.perf_counter() - w0
                    print(f"{preset:6s}  {obj:11s}  {inter:11s}  {r.n_frames:6d}  {r.width}x{r.height:<4d} {cpu:7.1f} {wall:8.1f}  "
                          f"{r.occlusion_mean:11.3f}  {r.occlusion_in_band:13.2f}  {r.object_travel:8.3f}  {r.object_rotation:7.2f}  {len(r.contacts):8d}", flush=True)
        if not a.no_geometry:
            print("\n# depth-on-surface check, noise off, 640x480 (distances in mm)")
            print("object       frames  points  median  p90")
            for obj in objects:
                spec = SynthSpec(object=obj, interaction="push", seed=a.seed, preset="full", n_frames=31, noise=False)
                r = make_session(spec, Path(tmp) / f"geo_{obj}")
                d = surface_error(r.session_dir, [0, 15, 30]) * 1e3
                print(f"{obj:11s}  {3:6d}  {len(d):6d}  {np.median(d):6.3f}  {np.percentile(d, 90):5.3f}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
