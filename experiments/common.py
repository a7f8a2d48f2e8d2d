"""Shared helpers of the experiment scripts that fit the data sets (``paper_table.py``,
``sweep_population.py``, ``point_budget.py``, ``far_bounds.py``).

One place for each idea (the machine record is in ``machine.py``, logging, atomic
files and number formats in ``outputs.py``):

- data sets: :func:`ensure_data` (``make data`` when ``data/`` lacks a model),
  :func:`load_dataset`, :func:`select_images`, :func:`load_image` (depth, cloud, truth);
- configurations: :func:`make_config` (FitConfig defaults plus overrides),
  :func:`planned_evaluations` / :func:`match_generations` (evaluation budgets),
  :func:`run_fingerprint` (what a stored run depends on);
- one fit, scored: :func:`fit_image`; a found pose against the truth: :func:`pose_costs`,
  :func:`miss_verdict`;
- the resumable run store: :class:`RunStore` (one JSON file per finished fit) and
  :class:`FitRunner` (skips stored fits, warms the compiler up once per config);
- the machine a fit ran on: :func:`machine_info` (``machine.py``'s, with the code's fingerprint);
- summaries: :func:`seed_stats`.

The scripts run from the repository root or anywhere else (``python experiments/x.py``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
import sys
import time
from typing import NamedTuple

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for _p in (ROOT, HERE):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import numpy as np  # noqa: E402
from machine import machine_id, now_iso  # noqa: E402
from machine import machine_info as _machine_info  # noqa: E402
from outputs import log, rel, write_json  # noqa: E402

from jaxpose.io.atomic import to_jsonable  # noqa: E402
from jaxpose.io.skeleton_file import load_skeleton  # noqa: E402
from jaxpose.io.truth import read_links  # noqa: E402
from jaxpose.metrics import evaluate  # noqa: E402
from jaxpose.pipeline import InputOptions, load_observation  # noqa: E402
from jaxpose.search import FitConfig, fit_cloud  # noqa: E402
from jaxpose.search.coarse import coarse_switch  # noqa: E402
from jaxpose.skeleton import Skeleton  # noqa: E402

DATA_DIR = os.path.join(ROOT, "data")
RESULTS_DIR = os.path.join(HERE, "results")
RUNS_DIR = os.path.join(RESULTS_DIR, "runs")  # git-ignored
MODELS = ("spider", "humanoid")
METRICS = ("pcp", "pcp_10cm", "pck_10cm", "mpjpe_mm")


# --------------------------------------------------------------------------- data


class Dataset(NamedTuple):
    model: str
    folder: str
    skeleton: Skeleton
    index: dict
    fingerprint: str  # sha256 of index.json (changes when the data are regenerated differently)

    @property
    def entries(self) -> list[dict]:
        return self.index["images"]


class Image(NamedTuple):
    model: str
    name: str
    entry: dict  # the index.json entry (image, background, truth, metadata)
    depth: np.ndarray  # metres
    intrinsics: object  # jaxpose.camera.Intrinsics
    cloud: object  # jaxpose.objective.Cloud
    truth: dict  # {"names", "start" (L, 3), "end" (L, 3)} in the skeleton's link order


def ensure_data(models, data_dir: str = DATA_DIR) -> None:
    """Write the data sets that ``data_dir`` lacks, with ``make data``'s code (seed 0)."""
    missing = [m for m in models if not os.path.exists(os.path.join(data_dir, m, "index.json"))]
    if not missing:
        return
    from make_data import write_dataset

    os.makedirs(data_dir, exist_ok=True)
    for m in missing:
        log(f"{rel(os.path.join(data_dir, m))}: missing, generating it (experiments/make_data.py) ...")
        write_dataset(m, data_dir)


def load_dataset(model: str, data_dir: str = DATA_DIR) -> Dataset:
    folder = os.path.join(data_dir, model)
    path = os.path.join(folder, "index.json")
    with open(path, "rb") as f:
        raw = f.read()
    index = json.loads(raw)
    skel = load_skeleton(index["skeleton"]["name"])
    return Dataset(model, folder, skel, index, hashlib.sha256(raw).hexdigest()[:12])


def select_images(ds: Dataset, spec=None) -> list[dict]:
    """Index entries: all (``None``), ``n`` evenly spread through the index (an int), or by name (strings).

    ``n`` images are those at positions ``floor((i + 1/2) * N / n)``, ``i = 0 .. n-1``
    (for the spider's 4 poses x 5 inclinations this mixes poses and inclinations).
    """
    entries = ds.entries
    if spec is None:
        return list(entries)
    if isinstance(spec, int):
        return spread(entries, spec)
    by_name = {e["name"]: e for e in entries}
    unknown = [s for s in spec if s not in by_name]
    if unknown:
        raise SystemExit(f"{ds.model}: no image named {', '.join(unknown)} (have {', '.join(by_name)})")
    return [by_name[s] for s in spec]


def spread(items: list, k: int) -> list:
    """``k`` of ``items`` evenly spread: positions ``floor((i + 1/2) * N / k)``."""
    n = len(items)
    k = max(1, min(k, n))
    return [items[int((i + 0.5) * n / k)] for i in range(k)]


def parse_images_arg(values):
    """``--images``: nothing (all), one integer (that many per model) or image names."""
    if not values:
        return None
    if len(values) == 1 and values[0].isdigit():
        return int(values[0])
    return list(values)


def depth_options(ds: Dataset, entry: dict) -> InputOptions:
    """How every experiment turns a data set image into a cloud (InputOptions defaults otherwise)."""
    k = ds.index["intrinsics"]
    return InputOptions(
        intrinsics=f"{k['fx']},{k['fy']},{k['cx']},{k['cy']}",
        depth_scale=ds.index.get("depth_scale", InputOptions.depth_scale),
        background=os.path.join(ds.folder, entry["background"]) if entry.get("background") else None,
    )


def depth_options_record(ds: Dataset) -> dict:
    """The depth options of a data set, without the per-image background path."""
    d = dataclasses.asdict(depth_options(ds, ds.entries[0]))
    d["background"] = "<image>_background.png" if d["background"] else None
    return d


_IMAGES: dict = {}


def load_image(ds: Dataset, entry: dict) -> Image:
    """Depth, cloud and truth of one data set image (cached)."""
    key = (ds.folder, entry["name"])
    if key not in _IMAGES:
        depth, k, cloud = load_observation(os.path.join(ds.folder, entry["image"]), depth_options(ds, entry))
        t = read_links(os.path.join(ds.folder, entry["truth"]))
        order = [t.names.index(n) for n in ds.skeleton.link_names]
        truth = {"names": list(ds.skeleton.link_names), "start": t.start[order], "end": t.end[order]}
        _IMAGES[key] = Image(ds.model, entry["name"], entry, depth, k, cloud, truth)
    return _IMAGES[key]


# --------------------------------------------------------------------------- configurations


def make_config(base: FitConfig, overrides: dict | None = None) -> FitConfig:
    """``base`` with FitConfig fields replaced; ``overrides["objective"]`` replaces ObjectiveConfig fields."""
    overrides = dict(overrides or {})
    obj = overrides.pop("objective", None)
    cfg = dataclasses.replace(base, **overrides)
    if obj:
        cfg = dataclasses.replace(cfg, objective=dataclasses.replace(cfg.objective, **obj))
    return cfg.validate()


def planned_evaluations(config: FitConfig, n_points: int = InputOptions.max_points, skel=None) -> dict:
    """Objective and gradient evaluations a fit with ``config`` will count (mirrors jaxpose/search/).

    ``P`` per generation (the first generation evaluates the initial population); with
    the memetic step (GA) ``m * memetic_steps`` gradients, ``m = min(memetic_top, P)``,
    after every epoch (every ``memetic_every`` generations and after a shorter last
    epoch); the final refinement takes ``c * final_refine_steps`` gradients for its
    ``c`` candidates (GA: ``min(final_refine_top, P)``, otherwise 1); a coarse-to-fine GA
    rescores its population and best (``P + 1``) once, on a cloud of ``n_points``;
    times ``islands``; the limb sweep's evaluations once per search (``skel`` needed when it is
    on); all of it once per search of the fit (``config.searches``: the portfolio's and the turns', per restart;
    with adaptive restarts the most a fit runs).
    :meth:`FitRunner.run` compares this with every fit's actual counts.
    """
    if config.generations is None:
        raise ValueError("planned_evaluations: resolve the generations first (config.for_skeleton(skel))")
    P, G = config.population, config.generations
    obj, grad = G * P, 0
    if config.memetic_on:
        grad += math.ceil(G / config.epoch) * min(config.memetic_top, P) * config.memetic_steps
    if config.final_refine_steps > 0 and config.final_refine_top > 0:
        c = min(config.final_refine_top, P) if config.algorithm == "ga" else 1
        grad += c * config.final_refine_steps
    if coarse_switch(config, n_points) is not None:
        obj += P + 1
    isl = getattr(config, "islands", 1)
    obj, grad = obj * isl, grad * isl
    if config.limb_sweep or config.pivot_sweep:
        if skel is None:
            raise ValueError("planned_evaluations: a sweep's evaluations depend on the skeleton (pass skel)")
        from jaxpose.search.sweep import sweep_counts

        s_obj, s_grad = sweep_counts(skel, config)
        obj, grad = obj + s_obj, grad + s_grad
    n = config.searches
    return {"objective": obj * n, "gradient": grad * n, "total": (obj + grad) * n}


def match_generations(config: FitConfig, target: dict, what: str = "total", skel=None) -> FitConfig:
    """``config`` with the generation count whose planned ``what`` evaluations ("total" =
    objective + gradient, or "objective") come closest to ``target[what]`` (ties: more)."""
    if what == "none":
        return config
    goal = target[what]
    count = lambda g: planned_evaluations(dataclasses.replace(config, generations=g), skel=skel)[what]  # noqa: E731
    slope = max(count(config.generations + 1) - count(config.generations), 1)
    g0 = max(1, config.generations + int(round((goal - count(config.generations)) / slope)))
    best = min(range(max(1, g0 - 3), g0 + 4), key=lambda g: (abs(count(g) - goal), -g))
    return dataclasses.replace(config, generations=best)


def _code_fingerprint() -> str:
    """sha256 over the jaxpose modules loaded by this module's imports (the code a fit
    runs) and skeletons/: a stored run is reused only by the same code."""
    h = hashlib.sha256()
    pkg = os.path.join(ROOT, "jaxpose") + os.sep
    files = {os.path.abspath(m.__file__) for m in list(sys.modules.values())
             if getattr(m, "__file__", None) and os.path.abspath(m.__file__).startswith(pkg)}
    for d, dirs, names in os.walk(os.path.join(ROOT, "skeletons")):
        files |= {os.path.join(d, n) for n in names}
    for p in sorted(files):
        h.update(os.path.relpath(p, ROOT).encode())
        with open(p, "rb") as f:
            h.update(hashlib.sha256(f.read()).digest())
    return h.hexdigest()[:12]


CODE_FINGERPRINT = _code_fingerprint()  # computed once, right after the imports above


def code_fingerprint() -> str:
    return CODE_FINGERPRINT


def short_hash(obj) -> str:
    return hashlib.sha256(json.dumps(to_jsonable(obj), sort_keys=True).encode()).hexdigest()[:10]


def run_fingerprint(ds: Dataset, config: FitConfig) -> str:
    """Hash of everything a fit's outcome depends on besides image and seed: the config,
    the depth options, the data set (index.json) and the code (:data:`CODE_FINGERPRINT`)."""
    return short_hash({"config": config.to_dict(), "depth": depth_options_record(ds), "data": ds.fingerprint,
                       "code": code_fingerprint()})


# --------------------------------------------------------------------------- one fit


def fit_image(ds: Dataset, img: Image, config: FitConfig, seed: int) -> dict:
    """Fit one image and score it against its truth; a JSON-ready record.

    ``wall_seconds`` is the fit's own wall time (:attr:`FitResult.wall_time`: cloud
    to result, compilation included when this config was not compiled yet);
    ``epoch_times`` holds ``[generation, seconds since the call]`` after every
    compiled chunk (the progress callback; it waits for the chunk's result).
    """
    config = config.for_skeleton(ds.skeleton)
    epochs: list = []
    t0 = time.perf_counter()

    def progress(generation, *_):
        epochs.append([int(generation), time.perf_counter() - t0])

    res = fit_cloud(img.cloud, ds.skeleton, seed, config, progress)
    call = time.perf_counter() - t0
    start, end = np.asarray(res.links.start, np.float64), np.asarray(res.links.end, np.float64)
    ev = evaluate(start, end, img.truth["start"], img.truth["end"], ds.skeleton)
    return {
        "model": ds.model,
        "image": img.name,
        "seed": int(seed),
        "algorithm": config.algorithm,
        "population": config.population,
        "generations": config.generations,
        "symmetric": ev["symmetric"],
        "strict": ev["strict"],
        "cost": float(res.cost),
        "objective_evaluations": int(res.objective_evaluations),
        "gradient_evaluations": int(res.gradient_evaluations),
        "distance_evaluations": float(res.distance_evaluations),
        "wall_seconds": float(res.wall_time),
        "call_seconds": call,
        "epoch_times": epochs,
        "links": {"names": list(ds.skeleton.link_names), "start": start.tolist(), "end": end.tolist()},
        "meta": {k: v for k, v in img.entry.items() if k not in ("image", "background", "truth")},
        "machine": machine_id(),
        "finished": now_iso(),
    }


def pose_costs(cloud, skel: Skeleton, config: FitConfig, posed) -> tuple[np.ndarray, dict]:
    """The objective of a fit of ``config`` (the same terms and weights as its ``result.cost``)
    for posed capsules ``posed`` = ``[(start, end, radius), ...]`` (each ``(L, 3), (L, 3), (L,)``,
    the cloud's frame) on ``cloud``: ``(costs (P,), {term: (P,)})``.  The diagnosis of a miss weighs
    the found pose against the truth with it (docs/experiments.md, "Hard poses: the diagnosis")."""
    import jax.numpy as jnp

    from jaxpose.objective import collision_cost, data_cost, free_space_cost, observe, population_cost
    from jaxpose.search.cost import objective_pairs

    obj = config.for_skeleton(skel).objective
    obs = observe(cloud, obj)
    pairs = objective_pairs(skel, obj)
    s, e, r = (jnp.asarray(np.stack([np.asarray(p[i], np.float64) for p in posed]), jnp.float32) for i in range(3))
    costs = np.asarray(population_cost(obs, s, e, r, obj, pairs=pairs), np.float64)
    terms = {"data": data_cost(obs.cloud, obs.sigma, s, e, r, obj.block)}
    if obj.free_space_weight != 0:
        terms["free_space"] = obj.free_space_weight * free_space_cost(obs.fmap, obs.sigma, s, e,
                                                                      obj.free_space_samples, r, obj.max_range)
    if pairs is not None:
        terms["collision"] = obj.collision_weight * collision_cost(pairs, obs.sigma, s, e, r, obj.collision_margin)
    return costs, {k: np.asarray(v, np.float64) for k, v in terms.items()}


COST_MARGIN = 0.002  # a found pose this much above the truth's cost: a search failure (a better optimum exists)
VISIBLE = 0.5  # a link with at least this visible fraction is one the camera sees


def miss_verdict(found_cost: float, truth_cost: float, margin: float = COST_MARGIN) -> str:
    """``"search"`` when the found pose costs more than the truth by ``margin`` or more, else ``"objective"``."""
    return "search" if found_cost > truth_cost + margin else "objective"


# --------------------------------------------------------------------------- run store


def run_key(*parts) -> str:
    """A file-name-safe key from its parts, joined by ``__``."""
    return "__".join(re.sub(r"[^A-Za-z0-9._=+-]+", "-", str(p)) for p in parts)


class RunStore:
    """Finished fits, one JSON file each (``<folder>/<key>.json``, written atomically).

    A run killed at any point loses only the fit in progress; a rerun skips every stored key.
    """

    def __init__(self, folder: str):
        self.folder = folder
        os.makedirs(folder, exist_ok=True)

    def path(self, key: str) -> str:
        return os.path.join(self.folder, key + ".json")

    def get(self, key: str) -> dict | None:
        p = self.path(key)
        if not os.path.exists(p):
            return None
        try:
            with open(p) as f:
                return json.load(f)
        except (OSError, json.JSONDecodeError) as e:  # cannot happen with atomic writes, but never trust
            log(f"warning: {rel(p)}: unreadable ({e}); running that fit again")
            return None

    def put(self, key: str, record: dict) -> None:
        write_json(self.path(key), record)


class FitRunner:
    """Runs fits through a :class:`RunStore`.

    Before the first fit that has to run for a (model, config), a *warm-up* fit of the
    same config on the same image and seed compiles everything; it is stored as
    ``warmup__...`` (its wall time minus the real fit's is the compile time, see
    :func:`compile_seconds`) and not scored further.  Every fit that runs prints one
    progress line; stored fits are skipped silently and counted.
    """

    def __init__(self, store: RunStore, total: int):
        self.store = store
        self.total = total
        self.done = 0
        self.skipped = 0
        self.ran = 0
        self.warm: set = set()
        self.warned: set = set()

    def keys(self, ds: Dataset, image: str, label: str, config: FitConfig, seed: int) -> tuple[str, str]:
        fp = run_fingerprint(ds, config.for_skeleton(ds.skeleton))
        return run_key(ds.model, image, label, f"seed{seed}", fp), run_key("warmup", ds.model, label, fp)

    def run(self, ds: Dataset, entry: dict, label: str, config: FitConfig, seed: int, extra: dict | None = None,
            quiet_skip: bool = True) -> dict:
        config = config.for_skeleton(ds.skeleton)  # generations resolved (FitConfig.generations=None: automatic)
        key, wkey = self.keys(ds, entry["name"], label, config, seed)
        self.done += 1
        rec = self.store.get(key)
        if rec is not None:
            self.skipped += 1
            return rec
        img = load_image(ds, entry)
        if wkey not in self.warm:
            self._warm_up(ds, img, label, config, seed, wkey)
        rec = fit_image(ds, img, config, seed)
        rec.update({"label": label, "key": key, "fingerprint": run_fingerprint(ds, config),
                    "planned_evaluations": planned_evaluations(config, skel=ds.skeleton), **(extra or {})})
        self._check_counts(rec, config, label, ds.skeleton)
        self.store.put(key, rec)
        self.ran += 1
        s = rec["symmetric"]
        shown = lambda x: "-" if x is None else f"{x:.3f}"  # noqa: E731 - PCP is None with no link scored
        log(f"[{self.done:>4}/{self.total}] {ds.model:<8} {img.name:<16} {label:<20} seed {seed}: "
            f"PCP {shown(s['pcp'])} (strict {shown(rec['strict']['pcp'])}, MPJPE {s['mpjpe_mm']:5.0f} mm) "
            f"{rec['wall_seconds']:7.2f} s")
        return rec

    def _warm_up(self, ds, img, label, config, seed, wkey):
        log(f"         {ds.model:<8} {img.name:<16} {label:<20} warm-up (compiling P={config.population}, "
            f"G={config.generations}) ...")
        rec = fit_image(ds, img, config, seed)
        rec.update({"label": label, "warmup": True, "fingerprint": run_fingerprint(ds, config)})
        if self.store.get(wkey) is None:  # keep the first warm-up (a cold process either way)
            self.store.put(wkey, rec)
        self.warm.add(wkey)
        log(f"         {'':<8} {'':<16} {'':<20} warm-up took {rec['wall_seconds']:.1f} s")

    def _check_counts(self, rec, config, label, skel):
        plan = planned_evaluations(config, skel=skel)
        got = (rec["objective_evaluations"], rec["gradient_evaluations"])
        if config.restart_apart and config.restarts > 1:  # adaptive: whole rounds of the plan, at least one
            r = config.restarts
            rounds = [(plan["objective"] // r * k, plan["gradient"] // r * k) for k in range(1, r + 1)]
        else:
            rounds = [(plan["objective"], plan["gradient"])]
        if got not in rounds and label not in self.warned:
            self.warned.add(label)
            log(f"warning: {label}: the fit counted {got[0]} objective + {got[1]} gradient evaluations, "
                f"experiments/common.py planned {plan['objective']} + {plan['gradient']}: "
                "planned_evaluations() no longer mirrors jaxpose/search/ (budgets may not match)")

    def warmup_record(self, ds: Dataset, label: str, config: FitConfig) -> dict | None:
        return self.store.get(self.keys(ds, "", label, config, 0)[1])


def compile_seconds(warmup: dict | None, records: list[dict]) -> float | None:
    """Warm-up wall time minus the wall time of the real fit of the same image and seed
    (or, when that one is not among ``records``, minus their median)."""
    if not warmup or not records:
        return None
    same = [r["wall_seconds"] for r in records if r["image"] == warmup["image"] and r["seed"] == warmup["seed"]]
    ref = same[0] if same else float(np.median([r["wall_seconds"] for r in records]))
    return max(0.0, warmup["wall_seconds"] - ref)


# --------------------------------------------------------------------------- machine


def machine_info() -> dict:
    """:func:`machine.machine_info` with the fingerprint of the code the fits ran (:data:`CODE_FINGERPRINT`)."""
    return _machine_info(jaxpose_code=code_fingerprint())


# --------------------------------------------------------------------------- summaries


def mean_scored(values) -> float | None:
    """Mean of the values that are not ``None`` (a metric a record could not score, e.g. PCP
    for a skeleton whose links all have length zero); ``None`` when none is left."""
    vals = [float(v) for v in values if v is not None]
    return float(np.mean(vals)) if vals else None


def seed_stats(records: list[dict], value) -> dict:
    """``mean`` of ``value(record)`` over all records, and ``std`` over seeds of the per-seed
    means (sample standard deviation; ``None`` with one seed); ``per_seed`` means.  Records
    whose value is ``None`` (not scored) are left out of every mean."""
    records = [r for r in records if value(r) is not None]
    if not records:
        return {"mean": None, "std": None, "per_seed": {}}
    seeds = sorted({r["seed"] for r in records})
    per_seed = {s: mean_scored(value(r) for r in records if r["seed"] == s) for s in seeds}
    std = float(np.std(list(per_seed.values()), ddof=1)) if len(seeds) > 1 else None
    return {"mean": mean_scored(value(r) for r in records), "std": std, "per_seed": per_seed}


def flat_row(rec: dict) -> dict:
    """The scalar columns of a fit record (for CSV files)."""
    row = {k: rec.get(k) for k in ("model", "image", "label", "algorithm", "seed", "population", "generations",
                                   "objective_evaluations", "gradient_evaluations", "distance_evaluations",
                                   "wall_seconds", "cost")}
    for m in METRICS:
        row[m] = rec["symmetric"][m]
        row[f"{m}_strict"] = rec["strict"][m]
    meta = rec.get("meta") or {}
    row["inclination_deg"] = meta.get("inclination_deg")
    row["occluded_links"] = len(meta.get("occluded_links") or [])
    return row


CSV_METRIC_COLUMNS = [c for m in METRICS for c in (m, f"{m}_strict")]
