"""Write the paper's synthetic data sets to data/ (``make data``); deterministic.

- data/spider/: 4 poses x 5 inclinations (0, 15, 30, 45, 60 degrees) = 20 images
- data/humanoid/: 4 subjects (different proportions) x 8 natural poses = 32 images

- data/sequences/: per model two motion sequences and one with a gap (the subject
  out of view for 8 frames, then back elsewhere), 90 frames at 30 fps each

Every image comes with its background-only image (floor and clutter) and a
ground-truth JSON; data/<model>/index.json lists them.  Kinect v1 sensor model on.
A different --seed gives a different (unseen) set of images.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time

from outputs import log

from jaxpose import datasets as D
from jaxpose import render as R
from jaxpose.io.atomic import write_json
from jaxpose.io.skeleton_file import load_skeleton
from jaxpose.io.truth import write_view

MODELS = ("spider", "humanoid")


def write_dataset(model: str, out_dir: str, seed: int = 0, quiet: bool = False) -> dict:
    skeleton_file = f"skeletons/{model}.toml"
    skel = load_skeleton(model)
    sensor = R.SensorModel()
    make = D.spider_dataset if model == "spider" else D.humanoid_dataset
    t0 = time.time()
    samples = make(skel, seed=seed, sensor=sensor)
    return write_samples(skel, samples, os.path.join(out_dir, model), skeleton_file, seed, sensor, model,
                         quiet=quiet, t0=t0)


def write_samples(skel, samples, folder: str, skeleton_file: str, seed: int, sensor=None, model: str | None = None,
                  extra: dict | None = None, quiet: bool = False, t0: float | None = None) -> dict:
    """Write ``samples`` (:class:`jaxpose.datasets.Sample`: name, view, meta) to ``folder``: per image the
    depth PNG, the background PNG and the truth JSON, and ``index.json`` listing them.

    ``sensor`` is the :class:`~jaxpose.render.SensorModel` the images were made with (``None``:
    another renderer's; say what it was in ``extra``, whose keys are added to the index).
    """
    t0 = time.time() if t0 is None else t0
    os.makedirs(folder, exist_ok=True)
    entries = []
    for s in samples:
        paths = {kind: os.path.join(folder, f"{s.name}_{kind}")
                 for kind in ("depth.png", "background.png", "truth.json")}
        write_view(paths["depth.png"], paths["truth.json"], skel, s.view, paths["background.png"], skeleton_file,
                   sensor, {**s.meta, "seed": seed, "name": s.name})
        occluded = [n for n, v in zip(skel.link_names, s.view.visible) if v < 0.5]
        entries.append({
            "name": s.name,
            "image": os.path.basename(paths["depth.png"]),
            "background": os.path.basename(paths["background.png"]),
            "truth": os.path.basename(paths["truth.json"]),
            "occluded_links": occluded,
            **s.meta,
        })
    k = samples[0].view.intrinsics
    index = {
        "model": model or skel.name,
        "skeleton": {"name": skel.name, "file": skeleton_file},
        "seed": seed,
        "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height},
        "depth_scale": 0.001,
        "sensor": dataclasses.asdict(sensor) if sensor is not None else None,
        "images": entries,
        **(extra or {}),
    }
    write_json(os.path.join(folder, "index.json"), index)
    if not quiet:
        n_occ = sum(1 for e in entries if e["occluded_links"])
        log(f"{folder}: {len(entries)} images ({n_occ} with a link less than half visible) "
              f"in {time.time() - t0:.1f} s")
    return index


SEQUENCE_FRAMES = 90
SEQUENCE_GAP = (40, 8)  # the gap sequences: out of view for 8 frames from frame 40


def sequence_set(model: str, skel, seed: int = 0, frames: int = SEQUENCE_FRAMES):
    """The motion sequences of a model: two plain ones and one with a gap (:mod:`jaxpose.sequences`)."""
    from jaxpose import sequences as S

    make = S.spider_sequence if model == "spider" else S.humanoid_sequence
    return [make(skel, seed=seed, frames=frames, index=0), make(skel, seed=seed, frames=frames, index=1),
            make(skel, seed=seed, frames=frames, gap=SEQUENCE_GAP, index=0)]


def write_sequences(model: str, out_dir: str, seed: int = 0, quiet: bool = False) -> list[str]:
    """data/sequences/<model>_{motion0,motion1,gap0}/ (jaxpose/io/sequence_file.py's layout)."""
    from jaxpose.io.sequence_file import write_sequence

    skel = load_skeleton(model)
    t0 = time.time()
    names = []
    for seq in sequence_set(model, skel, seed):
        write_sequence(os.path.join(out_dir, "sequences", seq.name), skel, seq, f"skeletons/{model}.toml",
                       R.SensorModel())
        names.append(seq.name)
    if not quiet:
        log(f"{out_dir}/sequences: {', '.join(names)} ({SEQUENCE_FRAMES} frames each) in {time.time() - t0:.1f} s")
    return names


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="data", help="output folder (default data/)")
    ap.add_argument("--seed", type=int, default=0, help="seed (default 0: the reference data sets)")
    ap.add_argument("--models", nargs="+", default=list(MODELS), choices=MODELS)
    ap.add_argument("--no-sequences", action="store_true", help="leave out the motion sequences (data/sequences/)")
    args = ap.parse_args(argv)
    for m in args.models:
        write_dataset(m, args.out, args.seed)
        if not args.no_sequences:
            write_sequences(m, args.out, args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
