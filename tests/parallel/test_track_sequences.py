"""``jaxpose track --sequences`` over several devices: two devices give the results of one,
the results equal the library's ``parallel.track_batch`` on the same clouds (read here by
``fit``'s reader, not the command's), each sequence's folder holds one sequence's files
(a shorter sequence's stop at its length), Ctrl-C keeps the chunks written, --resume
skips the sequences written, two processes joined by jax.distributed give the results
of one process with two devices, and bad options end with one line, write nothing and
start no search.

The command runs in a subprocess with two forced host devices (XLA_FLAGS is read when JAX
starts) and XLA's default settings, every run in that one process.  A three-link skeleton
keeps the two compilations (one and two devices) short; the library's call on two devices
reuses the command's program."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from test_sharding import forced_devices_env

SKELETON = """
name = "tiny"

[[link]]
name = "body"
joint = "ball"
length = 0.3
radius = 0.06

[[link]]
name = "arm"
parent = "body"
joint = "ball"
limits = [[-90, 90], [-90, 90], [0, 0]]
length = 0.25
radius = 0.04

[[link]]
name = "leg"
parent = "body"
joint = "ball"
attach = 0.0
limits = [[-90, 90], [-90, 90], [0, 0]]
length = 0.25
radius = 0.04
"""

DRIVER = r"""
import contextlib, io, json, os, shutil, sys
import numpy as np
import jax
import jaxpose
import jaxpose.parallel as par
from jaxpose.cli import main

d = sys.argv[1]
skel_file = f"{d}/tiny.toml"
open(skel_file, "w").write(sys.argv[2])
assert main(["render", "--skeleton", skel_file, "--sequence", "4", "--size", "160x120", "--out", f"{d}/render"]) == 0
k = json.load(open(f"{d}/render/index.json"))["intrinsics"]
intr = ",".join(str(k[n]) for n in ("fx", "fy", "cx", "cy"))
background = f"{d}/render/background.png"
frames = [f"{d}/render/depth/frame_{t:05d}.png" for t in range(4)]
from jaxpose.io.depth_file import read_depth
A, B = f"{d}/A", f"{d}/B.npy"  # A: 4 PNG frames in a folder; B: a stack of A's frames 3, 2, 1 in metres
os.makedirs(A)
for t, f in enumerate(frames):
    shutil.copy(f, f"{A}/f{t:03d}.png")
np.save(B, np.stack([read_depth(f)[0] for f in frames[3:0:-1]]).astype(np.float32))
os.makedirs(f"{d}/sub/A")  # a second sequence named A
shutil.copy(frames[0], f"{d}/sub/A/f000.png")
os.makedirs(f"{d}/badseq")  # a sequence with a frame that is not an image
shutil.copy(frames[0], f"{d}/badseq/a.png")
open(f"{d}/badseq/b.png", "wb").write(b"not a png")
tiny = ["--skeleton", skel_file, "--intrinsics", intr, "--background", background, "--max-points", "64",
        "--islands", "1", "--population", "8", "--generations", "4", "--no-refine", "--one-search", "--turns", "0",
        "--limb-sweep", "0", "--pivot-sweep", "0", "--track-population", "8", "--track-generations", "2",
        "--track-refine-steps", "2"]
log = {"A": A, "B": B, "calls": 0}

def run(name, *argv):
    os.makedirs(f"{d}/{name}")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["track", *tiny, "--out-dir", f"{d}/{name}", *argv])
    log[name] = {"rc": rc, "out": out.getvalue(), "err": err.getvalue(), "written": sorted(os.listdir(f"{d}/{name}"))}

real, real_chunks = par.track_batch, par.track_batch_chunks
def spy(*a, **kw):
    log["calls"] += 1
    return real_chunks(*a, **kw)
par.track_batch_chunks = spy
both = ["--sequences", A, B]
run("input_and_sequences", frames[0], *both)
run("video", *both, "--video", f"{d}/v.gif")
run("too_many", *both, "--devices", "3")
run("no_device", *both, "--devices", "0")
run("devices_alone", A, "--devices", "1")
run("resume_alone", A, "--resume")
run("same_name", "--sequences", A, f"{d}/sub/A")
run("missing", "--sequences", A, f"{d}/nowhere")
run("not_a_sequence", "--sequences", A, frames[0])
run("bad_frame", "--sequences", A, f"{d}/badseq")
log["refused_calls"] = log["calls"]
run("two", *both, "--devices", "2")

# one device, 2 frames a call: the program the Ctrl-C and --resume runs below reuse
import jaxpose.commands.track_sequences as ts
ts.CHUNK = 2
run("one", *both, "--devices", "1", "--quiet")

def stopped(*a, **kw):  # Ctrl-C while the second chunk of 2 frames runs
    chunks = real_chunks(*a, **kw)
    yield next(chunks)
    raise KeyboardInterrupt
par.track_batch_chunks = stopped
run("interrupted", *both, "--devices", "1")
par.track_batch_chunks = spy

def again(name, folder, *argv):  # into a folder written before
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["track", *tiny, "--out-dir", f"{d}/{folder}", *argv])
    log[name] = {"rc": rc, "out": out.getvalue(), "err": err.getvalue()}

calls = log["calls"]
again("resume_done", "one", *both, "--devices", "1", "--resume")
log["resume_done"]["calls"] = log["calls"] - calls
shutil.copytree(f"{d}/interrupted", f"{d}/resumed")
again("resume_interrupted", "resumed", *both, "--devices", "1", "--resume")
log["resume_interrupted"]["calls"] = log["calls"] - calls
log["tiny"] = tiny

# the library on the same clouds, read by fit's reader (PNG files) and by depth_to_cloud (the stack)
from jaxpose.camera import depth_to_cloud
from jaxpose.io.depth_file import parse_intrinsics
from jaxpose.objective import Cloud
from jaxpose.pipeline import InputOptions, read_observation
from jaxpose.search import FitConfig
from jaxpose.tracking import TrackConfig

opts = InputOptions(intr, 0.001, 0.3, 8.0, background, max_points=64)
seq_a = [read_observation(f"{A}/f{t:03d}.png", opts)[2] for t in range(4)]
stack = np.load(B)
bg = read_depth(background)[0]
seq_b = [depth_to_cloud(stack[t], parse_intrinsics(intr, stack.shape[1:]), 0.3, 8.0, bg, 64, 0) for t in range(3)]
seq_b.append(Cloud(np.zeros((64, 3), np.float32), np.zeros(64, np.float32)))  # the padding: an empty frame
clouds = Cloud(np.stack([[np.asarray(c.points) for c in s] for s in (seq_a, seq_b)]),
               np.stack([[np.asarray(c.weights) for c in s] for s in (seq_a, seq_b)]))
fit = FitConfig(islands=1, population=8, generations=4, memetic_steps=0, final_refine_steps=0,
                staged_alternatives=(), turns=0, limb_sweep=0, pivot_sweep=0)
cfg = TrackConfig(fit=fit, population=8, generations=2, refine_steps=2)
skel = jaxpose.load_skeleton(skel_file)
lib = real(clouds, skel, jax.random.key(0), cfg, par.device_mesh(2))
log["library"] = {"cost": np.asarray(lib.result.cost).tolist(), "mode": np.asarray(lib.mode).tolist(),
                  "ends": np.asarray(lib.result.links.end).tolist(), "config": cfg.for_skeleton(skel).to_dict()}
json.dump(log, open(f"{d}/log.json", "w"), default=str)
"""

LENGTHS = {"A": 4, "B": 3}
NAMES = {"A": [f"f{t:03d}" for t in range(4)], "B": [f"B_{t:05d}" for t in range(3)]}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("track_sequences")
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(d), SKELETON], env=forced_devices_env(2),
                          capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return d, json.loads((d / "log.json").read_text())


def sequence(d, run, seq):
    """``(track.json, [each frame's document])`` of one sequence of a run."""
    folder = d / run / seq
    track = json.loads((folder / "track.json").read_text())
    return track, [json.loads((folder / f"{n}.json").read_text()) for n in NAMES[seq][:len(track["frames"])]]


def ends(doc):
    return np.array([link["end"] for link in doc["links"]]) if "links" in doc else None


def test_two_devices_give_the_results_of_one(runs):
    d, log = runs
    assert log["two"]["rc"] == 0 and log["one"]["rc"] == 0, log["two"]["err"] + log["one"]["err"]
    out = log["two"]["out"].splitlines()
    assert out[0] == "2 sequences of 3 to 4 frames (padded to 4) on 2 CPU device(s): compiling and running one program"
    assert out[1].startswith(f"{log['A']}: 4 frames, ") and out[2].startswith(f"{log['B']}: 3 frames, ")
    assert out[3].startswith("tiny: 2 sequences, 7 frames on 2 CPU device(s) in ") and len(out) == 4
    assert log["one"]["out"] == "" and log["one"]["err"] == ""  # --quiet
    for seq in ("A", "B"):
        (t2, docs2), (t1, docs1) = sequence(d, "two", seq), sequence(d, "one", seq)
        assert [f["mode"] for f in t2["frames"]] == [f["mode"] for f in t1["frames"]]
        assert t2["summary"]["batch"]["devices"] == 2 and t1["summary"]["batch"]["devices"] == 1
        for a, b in zip(docs2, docs1):
            assert a["tracking"] == b["tracking"] and a["config"] == b["config"] and a["input"] == b["input"]
            if a["cost"] is None:
                assert b["cost"] is None
                continue
            np.testing.assert_allclose(a["cost"], b["cost"], rtol=1e-6)
            np.testing.assert_allclose(ends(a), ends(b), atol=1e-5)


def test_each_sequence_holds_one_sequences_files(runs):
    """DIR/<stem>/: the frames' documents and track.json as `jaxpose track` writes them for one
    sequence, no time per frame (null) and the batch's times; `jaxpose view` reads the folder."""
    from jaxpose.commands.track import summary
    from jaxpose.viewer.scene import load_view

    d, log = runs
    assert sorted(p.name for p in (d / "two").iterdir()) == ["A", "B"]
    for seq in ("A", "B"):
        files = sorted(p.name for p in (d / "two" / seq).iterdir())
        assert files == sorted([n + ".json" for n in NAMES[seq]] + ["track.json"])
        track, docs = sequence(d, "two", seq)
        assert track["skeleton"] == "tiny"
        for t, (entry, doc) in enumerate(zip(track["frames"], docs)):
            assert set(entry) == {"input", "frame", "mode", "cost", "wall_seconds"}
            assert entry["frame"] == doc["frame"] == t and entry["mode"] == doc["tracking"]
            assert entry["cost"] == doc["cost"] and entry["wall_seconds"] is None
            assert entry["input"] == (f"{log['A']}/f{t:03d}.png" if seq == "A" else f"B_{t:05d}")
            assert doc["schema"] == 1 and doc["timing"]["wall_seconds"] is None
            chunk = doc["timing"]["batch"]
            assert chunk == {**{k: track["summary"]["batch"][k] for k in ("sequences", "devices", "processes",
                                                                           "frames")},
                             "chunk_frames": [0, 4], "chunk_seconds": chunk["chunk_seconds"]}
            assert 0 < chunk["chunk_seconds"] <= track["summary"]["batch"]["wall_seconds"]
            assert len(doc["points"]) == doc["input"]["points_used"] > 0
            assert doc["input"]["depth"] == (f"f{t:03d}.png" if seq == "A" else "B.npy")
            if seq == "B":
                assert doc["input"]["stack_frame"] == t
        s = track["summary"]
        assert set(s) == set(summary([])) | {"batch"}
        assert s["frames"] == LENGTHS[seq] and s["global_frames"] >= 1
        assert s["tracked_frames"] + s["global_frames"] + s["lost_frames"] == LENGTHS[seq]
        for key in ("fps", "median_frame_seconds", "p90_frame_seconds", "first_frame_seconds",
                    "global_median_seconds"):
            assert s[key] is None
        b = s["batch"]
        assert (b["sequences"], b["devices"], b["processes"], b["frames"]) == (2, 2, 1, 4)
        assert b["wall_seconds"] >= b["compile_seconds"] > 0
        view = load_view(str(d / "two" / seq))
        assert [f.mode for f in view.frames] == [e["mode"] for e in track["frames"]]


def test_results_equal_the_library_track_batch(runs):
    from jaxpose.tracking import MODES

    d, log = runs
    lib = log["library"]
    cost, mode, lib_ends = np.array(lib["cost"], float), np.array(lib["mode"]), np.array(lib["ends"])
    assert cost.shape == (2, 4)
    assert mode[1, 3] == MODES.index("lost")  # the shorter sequence's padding: an empty frame, lost
    for i, seq in enumerate(("A", "B")):
        _, docs = sequence(d, "two", seq)
        assert docs[0]["config"] == lib["config"]["fit"]
        assert docs[0]["tracking_config"] == {k: v for k, v in lib["config"].items() if k != "fit"}
        for t, doc in enumerate(docs):
            assert doc["tracking"] == MODES[mode[i, t]]
            if doc["cost"] is None:
                continue
            np.testing.assert_allclose(doc["cost"], cost[i, t], rtol=1e-6)
            np.testing.assert_allclose(ends(doc), lib_ends[i, t], atol=1e-5)
    assert abs(cost[0, 0] - cost[1, 0]) > 1e-4  # the two sequences' first frames differ: a mix-up would show


def test_the_shorter_sequence_stops_at_its_length(runs):
    d, _ = runs
    track, _ = sequence(d, "two", "B")
    assert len(track["frames"]) == 3 and track["summary"]["frames"] == 3 and track["summary"]["batch"]["frames"] == 4
    assert not (d / "two" / "B" / "B_00003.json").exists()
    assert "lost" not in [f["mode"] for f in track["frames"]]  # the padding frame is not reported


def test_ctrl_c_keeps_the_chunks_written(runs):
    """Ctrl-C during the second chunk (2 frames a call here): exit 130, each sequence keeps its
    first chunk's frames and a track.json of them marked interrupted, equal to the full run's."""
    d, log = runs
    r = log["interrupted"]
    assert r["rc"] == 130 and "interrupted" in r["err"], r["err"]
    assert r["written"] == ["A", "B"]
    for seq in ("A", "B"):
        assert sorted(p.name for p in (d / "interrupted" / seq).iterdir()) == \
            sorted([n + ".json" for n in NAMES[seq][:2]] + ["track.json"])
        track, docs = sequence(d, "interrupted", seq)
        full, full_docs = sequence(d, "one", seq)
        assert track["summary"]["interrupted"] is True and track["summary"]["frames"] == 2
        assert "interrupted" not in full["summary"]
        assert [doc["timing"]["batch"]["chunk_frames"] for doc in docs] == [[0, 2], [0, 2]]
        for a, b in zip(docs, full_docs):  # the chunked program's frames: those of the whole batch
            assert a["tracking"] == b["tracking"]
            if a["cost"] is not None:
                np.testing.assert_allclose(a["cost"], b["cost"], rtol=1e-5)


def test_resume_skips_the_sequences_written_and_redoes_the_interrupted(runs):
    d, log = runs
    done = log["resume_done"]
    assert done["rc"] == 0 and done["calls"] == 0, done["err"]
    assert done["out"].splitlines() == ["2 of 2 sequences already written, skipped",
                                        f"every sequence is already written -> {d}/one"]
    again = log["resume_interrupted"]
    assert again["rc"] == 0 and again["calls"] == 1, again["err"]
    for seq in ("A", "B"):
        track, docs = sequence(d, "resumed", seq)
        full, full_docs = sequence(d, "one", seq)
        assert "interrupted" not in track["summary"] and track["summary"]["frames"] == LENGTHS[seq]
        assert [doc["cost"] for doc in docs] == [doc["cost"] for doc in full_docs]


@pytest.mark.slow  # two more processes, each compiling the search (about 30 s on 2 cores)
def test_two_processes_give_the_results_of_one_with_two_devices(runs, tmp_path):
    """``jaxpose track --sequences A B`` on two processes joined by jax.distributed (one CPU
    device each, CPU collectives): process 0 tracks A, process 1 B, each writes its own; the
    results are those of one process with two devices."""
    from test_distributed import free_port

    d, log = runs
    port, procs = free_port(), []
    for pid in range(2):
        env = forced_devices_env(1)
        env.update(JAXPOSE_DISTRIBUTED="1", JAX_COORDINATOR_ADDRESS=f"localhost:{port}", JAX_NUM_PROCESSES="2",
                   JAX_PROCESS_ID=str(pid))
        argv = [sys.executable, "-m", "jaxpose.cli", "track", *log["tiny"], "--out-dir", str(tmp_path),
                "--sequences", log["A"], log["B"]]
        procs.append(subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    outs = []
    try:
        for p in procs:
            out, err = p.communicate(timeout=300)
            assert p.returncode == 0, err[-3000:]
            outs.append(out)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    assert "\nprocess 0 of 2: 1 sequence of 4 frames each on 2 CPU device(s) of 2 processes" in "\n" + outs[0]
    assert f"process 1 of 2: {log['B']}: 3 frames, " in outs[1]
    for seq in ("A", "B"):
        track = json.loads((tmp_path / seq / "track.json").read_text())
        assert track["summary"]["batch"]["processes"] == 2 and track["summary"]["batch"]["devices"] == 2
        docs = [json.loads((tmp_path / seq / f"{n}.json").read_text()) for n in NAMES[seq]]
        _, want = sequence(d, "two", seq)
        for a, b in zip(docs, want):
            assert a["tracking"] == b["tracking"]
            if a["cost"] is None:
                assert b["cost"] is None
                continue
            np.testing.assert_allclose(a["cost"], b["cost"], rtol=1e-6)
            np.testing.assert_allclose(ends(a), ends(b), atol=1e-5)


@pytest.mark.parametrize("name, message", [
    ("input_and_sequences", "INPUT ({d}/render/depth/frame_00000.png) and --sequences exclude each other"),
    ("video", "--video works with one sequence (INPUT ...), not with --sequences"),
    ("too_many", "--devices must lie within 1 .. 2 (this machine's CPU devices), got 3"),
    ("no_device", "--devices must be >= 1, got 0"),
    ("devices_alone", "--devices works with --sequences"),
    ("resume_alone", "--resume works with --sequences"),
    ("same_name", "sequences {d}/A and {d}/sub/A would both write A/ in --out-dir"),
    ("missing", "--sequences {d}/nowhere: no such folder or file"),
    ("not_a_sequence", "--sequences {d}/render/depth/frame_00000.png: a sequence is a folder of frames or one "
                       "(T, H, W) .npy stack"),
    ("bad_frame", "{d}/badseq/b.png"),
])
def test_refusals_are_one_line_and_write_nothing(runs, name, message):
    d, log = runs
    r = log[name]
    assert r["rc"] == 2 and r["out"] == "" and r["written"] == []
    assert r["err"].startswith("jaxpose: error: ") and r["err"].count("\n") == 1, r["err"]
    assert message.format(d=d) in r["err"], r["err"]
    assert log["refused_calls"] == 0  # no search started for any of them
