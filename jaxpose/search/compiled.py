"""The search as compiled programs, cached by what they depend on, and :class:`Fitter`.

One fit is five kinds of program: the start, an epoch's generations, the
refinement (shared by the memetic step and the final one), the memetic step's
write-back, and the result.  They are compiled ahead of the first fit of a static
config and cloud size, XLA compiling one in a worker thread while Python traces the
next (docs/performance.md, "Compile time"), and reused by every later fit of the same
signature, whatever its traced settings (:class:`~jaxpose.search.config.FitParams`).
"""

from __future__ import annotations

import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import jax
import jax.numpy as jnp

from .._xla_flags import fast_compile_options
from ..objective import Cloud, cloud_spread
from ..skeleton import Skeleton
from ..errors import ConfigError, require_finite, require_integer
from .coarse import coarse_switch, rescore_all
from .config import FitConfig, FitParams
from .hypotheses import hypotheses as distinct_hypotheses
from .hypotheses import with_answers
from .loop import (EpochSteps, cheapest, cheapest_index, evaluation_counts, run_searches, search_epoch,
                   search_generations, search_init, search_result)
from .memetic import final_refine, memetic_apply, refine_top
from .state import FitResult, SearchState

# the programs that run once or a few times per fit compile with options that compile
# faster (same numbers: see jaxpose/_xla_flags.py); the generations keep XLA's
# defaults, which run them faster
_ONCE = fast_compile_options()
init_jit = jax.jit(search_init, static_argnames="config", compiler_options=_ONCE)
generations_jit = jax.jit(search_generations, static_argnames=("config", "length"))
refine_jit = jax.jit(refine_top, static_argnames=("config", "m"), compiler_options=_ONCE)
memetic_apply_jit = jax.jit(memetic_apply, static_argnames="config", compiler_options=_ONCE)
result_jit = jax.jit(search_result, static_argnames="config", compiler_options=_ONCE)
JIT_STEPS = EpochSteps(generations_jit, refine_jit, memetic_apply_jit)
rescore_jit = jax.jit(rescore_all, static_argnames="config", compiler_options=_ONCE)  # an anytime fit's early end


class CompiledSearch(NamedTuple):
    """The compiled programs of one static config and signature (:func:`compile_search`):
    ``init``, ``generations`` and ``apply`` by epoch length, ``refine`` by count, ``result``."""

    init: object
    generations: dict
    refine: dict
    apply: dict
    result: object

    def steps(self) -> EpochSteps:
        return EpochSteps(lambda sk, c, s, n: self.generations[n](sk, s),
                          lambda sk, c, s, m, steps: self.refine[m](sk, s, steps),
                          lambda sk, c, s, refined, h: self.apply[h.shape[0]](sk, s, refined, h))


def compile_search(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig, params: FitParams,
                   workers: int = 2) -> CompiledSearch:
    """Trace and compile every program of a fit of the static ``config`` ahead of time,
    XLA compiling one program in a worker thread while Python traces the next (XLA
    releases the interpreter lock while it compiles).  The programs are exactly those
    of ``init_jit``, ``generations_jit``, ...; only the order of the work changes."""
    lengths = sorted(set(config.epoch_lengths))
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        low = init_jit.lower(cloud, skel, key, config=config, params=params)
        init, st = pool.submit(low.compile), low.out_info
        gens, hist = {}, {}
        for n in lengths:
            low = generations_jit.lower(skel, config, st, length=n)
            gens[n], hist[n] = pool.submit(low.compile), low.out_info[1]
        steps = jax.ShapeDtypeStruct((), jnp.int32)
        counts = ([config.memetic_rows] if config.memetic_on else []) + (
            [config.final_rows] if config.final_refine_on else [])
        refine, refined = {}, {}
        for m in sorted(set(counts)):
            low = refine_jit.lower(skel, config, st, m, steps)
            refine[m], refined[m] = pool.submit(low.compile), low.out_info
        apply = {}
        if config.memetic_on:
            for n in lengths:
                low = memetic_apply_jit.lower(skel, config, st, refined[config.memetic_rows], hist[n])
                apply[n] = pool.submit(low.compile)
        final = refined[config.final_rows] if config.final_refine_on else None
        history = jax.ShapeDtypeStruct((config.generations,), jnp.float32)
        result = pool.submit(result_jit.lower(cloud, skel, config, st, history, final).compile)
        done = lambda d: {k: f.result() for k, f in d.items()}  # noqa: E731
        return CompiledSearch(init.result(), done(gens), done(refine), done(apply), result.result())
    finally:  # an error or Ctrl-C does not wait for the compilations still queued
        pool.shutdown(wait=False, cancel_futures=True)


def signature(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig, params: FitParams):
    """What a compiled fit depends on: the static config and the arguments' structure and types."""
    leaves, tree = jax.tree_util.tree_flatten((cloud, skel, key, params))
    return config, tree, tuple((x.shape, x.dtype) if hasattr(x, "dtype") else type(x) for x in leaves)


class ProgramCache:
    """Compiled searches by :func:`signature`, most recently used last, at most ``size``."""

    def __init__(self, size: int = 8):
        self.size = size
        self.entries: OrderedDict = OrderedDict()

    def __contains__(self, sig) -> bool:
        return sig in self.entries

    def get(self, cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig,
            params: FitParams) -> CompiledSearch:
        """The compiled search for this fit, from the cache or compiled now."""
        sig = signature(cloud, skel, key, config, params)
        if sig in self.entries:
            self.entries.move_to_end(sig)
        else:
            self.entries[sig] = compile_search(cloud, skel, key, config, params)
            while len(self.entries) > self.size:
                self.entries.popitem(last=False)
        return self.entries[sig]


PROGRAMS = ProgramCache()


def as_float32(cloud: Cloud) -> Cloud:
    return Cloud(jnp.asarray(cloud.points, jnp.float32), jnp.asarray(cloud.weights, jnp.float32))


class Fitter:
    """:func:`~jaxpose.search.fit`'s steps as compiled programs, epoch by epoch.

    The programs depend on the static part of ``config`` (:meth:`FitConfig.static`)
    and the cloud's size; they are compiled at the first fit of such a signature and
    reused after, whatever the rates and weights.  Step a fit by hand::

        fitter = Fitter(skeleton, config)
        st = fitter.init(cloud, key)
        hists = []
        for length in fitter.epoch_lengths:
            st, hist = fitter.step(st, length)
            hists.append(hist)
        result = fitter.finish(st, jnp.concatenate(hists))

    or call :meth:`run`, which does that with a progress callback.
    """

    def __init__(self, skeleton: Skeleton, config: FitConfig = FitConfig(), cache: ProgramCache = PROGRAMS):
        self.skeleton = skeleton
        self.config = config.validate().for_skeleton(skeleton)  # generations resolved
        self.params = self.config.params()
        self._static = self.config.static()
        self._cache = cache
        self._compiled: CompiledSearch | None = None

    @property
    def epoch_lengths(self) -> tuple[int, ...]:
        return self.config.epoch_lengths

    def init(self, cloud: Cloud, key: jax.Array, params: FitParams | None = None) -> SearchState:
        """The initial state for ``cloud`` (compiles the programs on the first use of its signature);
        ``params``: the traced settings (default the config's; a portfolio's search passes its own)."""
        cloud = as_float32(cloud)
        params = self.params if params is None else params
        self._compiled = self._cache.get(cloud, self.skeleton, key, self._static, params)
        return self._compiled.init(cloud, self.skeleton, key, params=params)

    def _programs(self) -> CompiledSearch:
        if self._compiled is None:
            raise RuntimeError("Fitter: call init(cloud, key) before step or finish")
        return self._compiled

    def step(self, st: SearchState, length: int) -> tuple[SearchState, jax.Array]:
        """One epoch of ``length`` generations (one of :attr:`epoch_lengths`); returns the
        state and the best cost after each generation ``(length,)``.  Runs the programs of
        the cloud size of the last :meth:`init`."""
        if length not in self.epoch_lengths:
            raise ConfigError(f"Fitter.step: an epoch of {length} generations; this fit's epochs are "
                              f"{sorted(set(self.epoch_lengths))}")
        return search_epoch(self.skeleton, self._static, st, length, self._programs().steps())

    def finish(self, st: SearchState, history) -> FitResult:
        """The final refinement and the best individual over all islands."""
        programs = self._programs()
        refine = lambda sk, c, s, m, steps: programs.refine[m](sk, s, steps)  # noqa: E731
        refined = final_refine(self.skeleton, self._static, st, refine)
        return programs.result(st.obs.cloud, self.skeleton, st, history, refined)

    def run(self, cloud: Cloud, key: jax.Array, progress=None, hypotheses: int = 1,
            time_budget: float | None = None) -> FitResult:
        """A whole fit; ``progress(generation, best_cost, evaluations)`` after every epoch
        (the generations run by all its searches in a row, up to ``generations * searches``).

        The searches of the portfolio run one after another with the same programs,
        then the turn searches (:attr:`FitConfig.turns`) about the portfolio's answer,
        all of it :attr:`FitConfig.restarts` times (:func:`~jaxpose.search.loop.run_searches`);
        the cheapest answer is returned, with the evaluations of all of them.
        ``hypotheses > 1``: also the best distinct poses the islands of the chosen
        search found (:func:`~jaxpose.search.hypotheses.hypotheses`), in ``FitResult.hypotheses``.
        ``time_budget`` (seconds of search, compilation excluded): an anytime fit in which
        each search ends after the epoch in which its share of the budget runs out, then
        refines and returns its best as usual; the history's generations not run repeat
        its last cost, and the evaluation counts are those made."""
        require_integer("hypotheses", hypotheses, 1)
        if time_budget is not None and not require_finite("time_budget", time_budget) > 0:
            raise ConfigError(f"time_budget must be > 0 seconds, got {time_budget}")
        t0 = time.perf_counter()
        n = self.config.searches
        share = None if time_budget is None else time_budget / n
        results, states, best, evals, done = [], [], float("inf"), 0, 0

        def search(k, params):
            nonlocal best, evals, done
            report, ran = None, [0]
            if progress is not None:  # generations counted as run (a budget can end a search early)
                def report(gen, cost, e, best=best, evals=evals, done=done):
                    ran[0] = gen
                    progress(done + gen, min(best, cost), evals + e)
            res, st = self._search(cloud, k, params, report, share)
            done += ran[0]
            results.append(res)
            states.append(st if hypotheses > 1 else None)  # only the hypotheses read the final states
            best = min(best, float(res.cost))
            evals += int(res.objective_evaluations) + int(res.gradient_evaluations)
            return res

        run_searches(self.skeleton, self.config, self.params, key, search, cloud)
        res = results[0] if n == 1 else cheapest(results)
        if hypotheses > 1:
            chosen = int(cheapest_index(jnp.stack([r.cost for r in results])))
            hyp = distinct_hypotheses(self.skeleton, self._static, states[chosen], results[chosen], hypotheses)
            others = [r for j, r in enumerate(results) if j != chosen]
            if others:  # the other searches' answers are candidates too
                hyp = with_answers(hyp, others, float(cloud_spread(states[chosen].obs.cloud)), hypotheses)
            res = res._replace(hypotheses=hyp)
        res = jax.block_until_ready(res)
        return res._replace(wall_time=jnp.asarray(time.perf_counter() - t0, jnp.float32))

    def _search(self, cloud: Cloud, key: jax.Array, params: FitParams, progress, time_budget):
        """One search of the portfolio: its :class:`FitResult` and final state."""
        st = self.init(cloud, key, params)
        hists, gen, t_search = [], 0, time.perf_counter()
        for length in self.epoch_lengths:
            st, h = self.step(st, length)
            hists.append(h)
            gen += length
            if progress is not None:
                progress(gen, float(h[-1]), int(sum(evaluation_counts(st))))
            if time_budget is not None:
                jax.block_until_ready(h)  # the clock must see the epoch done, not just queued
                if time.perf_counter() - t_search > time_budget:
                    break
        if gen < self.config.generations:  # stopped by the budget: the result program's history shape
            hists.append(jnp.full((self.config.generations - gen,), hists[-1][-1]))
            if (switch := coarse_switch(self._static, cloud.points.shape[0])) is not None and gen <= switch:
                st = rescore_jit(self.skeleton, self._static, st)  # costs on every point, as a full fit's
        return self.finish(st, jnp.concatenate(hists)), st


def fit_cloud(cloud: Cloud, skeleton: Skeleton, seed: int = 0, config: FitConfig = FitConfig(),
              progress=None, hypotheses: int = 1, time_budget: float | None = None) -> FitResult:
    """Convenience: :meth:`Fitter.run` with an integer seed."""
    return Fitter(skeleton, config).run(cloud, jax.random.key(seed), progress, hypotheses, time_budget)
