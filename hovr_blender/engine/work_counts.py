"""The work counts of a render: every ray's counters (kernels/args.py STAT_*, docs/traversal.md)
summed into the render's stats, a ray's work in field evaluations (ray_cost: what a frame split
over several devices balances its rows by), per counter its mean per ray and divergence over a
GPU warp's rays (work_counts: tests/perf's budgets), and the lanes of the search and traverse
launches that have work (LaneCounts). numpy only: the counters come back from the device."""
from __future__ import annotations

import numpy as np

WARP_SIZE = 32  # the rays a GPU warp runs together: the work counts' divergence blocks, lane occupancy
# a ray's work in the units of one field evaluation, from its counters (kernels/args.py STAT_*):
# each element segment costs about a Newton solve's evaluations, each face crossing the search
# polishes a few (2-4 map evaluations), and a ray a few for its search and finalize. A
# load-balancing estimate, not a timing model.
RAY_COST_BASE = 8.0
RAY_COST_SEGMENT = 16.0
RAY_COST_LOCATE = 4.0


def ray_cost(kernels, counts: np.ndarray, rays: int | np.ndarray = 1) -> np.ndarray:
    """The work of `rays` rays whose counters summed to `counts` (..., NUM_STATS), in field
    evaluations (RAY_COST_*)."""
    counts = np.asarray(counts, dtype=np.float64)
    return (counts[..., kernels.STAT_FIELD_EVALS] + counts[..., kernels.STAT_RESTRICTION_EVALS]
            + RAY_COST_SEGMENT * counts[..., kernels.STAT_SEGMENTS] + RAY_COST_LOCATE * counts[..., kernels.STAT_LOCATES]
            + RAY_COST_BASE * np.asarray(rays, dtype=np.float64))


def work_counts(kernels, ray_counts: np.ndarray) -> dict:
    """The work counts of a render (RenderResult.ray_counts): per counter, its mean per ray and its
    divergence, the mean over blocks of WARP_SIZE consecutive rays (a warp's rays in the first
    round: pixels in row order) of the block's largest count over its mean (1: every ray of a
    block works alike; blocks with no work are left out). Samples are field plus restriction
    evaluations; `work` is ray_cost's estimate."""
    c = np.asarray(ray_counts, dtype=np.int64).reshape(-1, kernels.NUM_STATS)
    series = {"bvh_candidates": c[:, kernels.STAT_BVH_CANDIDATES],
              "newton_search": c[:, kernels.STAT_NEWTON_SEARCH], "newton_walk": c[:, kernels.STAT_NEWTON_WALK],
              "newton_sample": c[:, kernels.STAT_NEWTON_SAMPLE],
              "element_locations": c[:, kernels.STAT_LOCATES], "segments": c[:, kernels.STAT_SEGMENTS],
              "samples": c[:, kernels.STAT_FIELD_EVALS] + c[:, kernels.STAT_RESTRICTION_EVALS],
              "walks": c[:, kernels.STAT_WALKS], "rounds": c[:, kernels.STAT_ROUNDS],
              "work": ray_cost(kernels, c)}
    rays = len(c)
    out = {"rays": rays}
    for name, v in series.items():
        v = np.asarray(v, dtype=np.float64)
        blocks = np.pad(v, (0, -rays % WARP_SIZE)).reshape(-1, WARP_SIZE)
        fill = np.minimum(WARP_SIZE, rays - WARP_SIZE * np.arange(len(blocks)))  # the last block's rays
        mean = blocks.sum(axis=1) / fill
        busy = mean > 0
        out[name] = {"per_ray": float(v.sum() / max(rays, 1)),
                     "divergence": float((blocks.max(axis=1)[busy] / mean[busy]).mean()) if busy.any() else 1.0}
    return out


# counter_stats' totals: those of row bands rendered or shaded apart add up
SUMMED_STATS = ("field_evaluations", "restriction_evaluations", "segments", "segments_empty", "segments_smooth",
                "segments_piecewise_smooth", "curved_locates", "walks", "bvh_candidates", "newton_iterations",
                "ray_rounds")


def banded_stats(stats: list, pixels: int) -> dict:
    """One image's stats from those of its row bands rendered or shaded apart (in row order): the
    first band's, but its rows and kernel timings, with SUMMED_STATS added up, samples_per_ray over
    the image's `pixels` and every band's warnings."""
    out = {k: v for k, v in stats[0].items() if k not in SUMMED_STATS + ("rows", "kernel_seconds")}
    for k in SUMMED_STATS:
        out[k] = int(sum(s[k] for s in stats))
    out["samples_per_ray"] = (out["field_evaluations"] + out["restriction_evaluations"]) / max(pixels, 1)
    out["warnings"] = sorted({w for s in stats for w in s.get("warnings", [])})
    return out


def counter_stats(kernels, counts: np.ndarray, pixels: int) -> dict:
    """The render's stats from the per-ray counters summed over the image (kernels/args.py STAT_*)."""
    return {
        "field_evaluations": int(counts[kernels.STAT_FIELD_EVALS]),
        "restriction_evaluations": int(counts[kernels.STAT_RESTRICTION_EVALS]),
        "samples_per_ray": float((counts[kernels.STAT_FIELD_EVALS] + counts[kernels.STAT_RESTRICTION_EVALS]) / pixels),
        "segments": int(counts[kernels.STAT_SEGMENTS]),
        "segments_empty": int(counts[kernels.STAT_EMPTY]),
        "segments_smooth": int(counts[kernels.STAT_SMOOTH]),
        "segments_piecewise_smooth": int(counts[kernels.STAT_PIECEWISE]),
        "curved_locates": int(counts[kernels.STAT_LOCATES]),
        "walks": int(counts[kernels.STAT_WALKS]),
        "bvh_candidates": int(counts[kernels.STAT_BVH_CANDIDATES]),
        "newton_iterations": int(counts[kernels.STAT_NEWTON_SEARCH] + counts[kernels.STAT_NEWTON_WALK]
                                 + counts[kernels.STAT_NEWTON_SAMPLE]),
        "ray_rounds": int(counts[kernels.STAT_ROUNDS]),
    }


class LaneCounts:
    """For render(ray_counts=True): per kernel, the lanes of its launches' 32-lane groups (the
    round's list in order, as a GPU's warps take it) that have work, over the lanes of the groups
    that have any (occupancy 1: a warp's lanes all work; 1/32: one works while 31 wait); and the
    traverse launches' divergence: over the groups with work, the mean of each group's largest
    lane's walk work (Newton iterations and steps) over its lanes' mean. Read on the host around
    the launches (a measurement: it waits for the device)."""

    def __init__(self, kernels):
        self.kernels = kernels
        self.busy = {"search": 0, "traverse": 0}
        self.lanes = {"search": 0, "traverse": 0}
        self.walk_ratio, self.walk_groups = 0.0, 0
        self._walking = None

    def count(self, kernel: str, rays, active: int, pixel_offset: int):
        ids = rays.active.numpy()[:active]
        nxt, phase = rays.next_element.numpy()[ids], rays.phase.numpy()[ids]
        work = (phase == 0) & ((nxt < 0) if kernel == "search" else (nxt >= 0))
        groups = np.pad(work, (0, -active % WARP_SIZE)).reshape(-1, WARP_SIZE)
        self.busy[kernel] += int(groups.sum())
        self.lanes[kernel] += WARP_SIZE * int(groups.any(axis=1).sum())
        if kernel == "traverse":
            self._walking = (ids + pixel_offset, self._walk_work(rays, ids + pixel_offset))

    def _walk_work(self, rays, pixels):
        c = rays.stats.numpy()[pixels]
        return c[:, self.kernels.STAT_NEWTON_WALK].astype(np.int64) + c[:, self.kernels.STAT_WALKS]

    def walked(self, rays):
        """After a traverse launch: its lanes' work (counted since count("traverse", ...))."""
        pixels, before = self._walking
        work = np.pad(self._walk_work(rays, pixels) - before, (0, -len(pixels) % WARP_SIZE)).reshape(-1, WARP_SIZE)
        busy = work.max(axis=1) > 0
        self.walk_ratio += float((work[busy].max(axis=1) / work[busy].mean(axis=1)).sum())
        self.walk_groups += int(busy.sum())

    def occupancy(self) -> dict:
        out = {k: self.busy[k] / self.lanes[k] if self.lanes[k] else 1.0 for k in self.busy}
        out["traverse_divergence"] = self.walk_ratio / self.walk_groups if self.walk_groups else 1.0
        return out
