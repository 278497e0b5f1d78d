"""The work-count guard (issue 28): each fixed scene's traversal work, counted per ray on the CPU,
stays within 10 % of the budget committed beside this file (work_budgets.json; how to update it:
tests/perf/work_counts.py). Counts, not times: they are the same on every run and every machine."""
import numpy as np
import pytest

from hovr_blender.engine.renderer import Renderer
from hovr_blender.engine.work_counts import work_counts
from hovr_blender.engine.view import RenderOptions

from ..helpers import BACKGROUND, curved_mixed_scene
from . import work_counts as wc

CASES = [(name, precision) for name, scene in wc.SCENES.items() for precision in scene.precisions]


@pytest.mark.parametrize("name,precision", CASES, ids=[f"{n}-{p}" for n, p in CASES])
def test_work_within_budget(name, precision):
    scene = wc.SCENES[name]
    missing = wc.missing_files(scene)
    if missing:
        pytest.skip(f"data file {', '.join(missing)} not found (tests/data or ../shared/data)")
    budget = wc.load_budgets()["scenes"].get(name, {}).get(precision)
    assert budget is not None, f"{name} {precision} has no budget: python -m tests.perf.work_counts --update --reason ..."
    counts = wc.measure(scene, precision)
    over = wc.over_budget(counts, budget)
    assert not over, f"{name} {precision}: " + "; ".join(over) + (
        " (a change that costs this work updates tests/perf/work_budgets.json in the same commit, saying why)")


@pytest.mark.parametrize("precision", ["float32", "float64"])
def test_counts_are_deterministic(precision):
    """Two renders of one curved scene count the same work, ray by ray."""
    mesh, tf, camera = curved_mixed_scene(1)
    r = Renderer(mesh, "cpu")
    opts = RenderOptions(precision=precision, device="cpu")
    a = r.render(camera(32, 18), tf, BACKGROUND, opts, ray_counts=True)
    b = r.render(camera(32, 18), tf, BACKGROUND, opts, ray_counts=True)
    assert a.ray_counts.shape == (18, 32, r._upload(precision).precision.kernels.NUM_STATS)
    assert np.array_equal(a.ray_counts, b.ray_counts)
    assert a.stats["newton_iterations"] > 0 and a.stats["bvh_candidates"] > 0


def test_divergence_figure():
    """The divergence is the mean over 32-ray blocks of the block's largest count over its mean."""
    from hovr_blender.engine.kernels import raycast

    counts = np.zeros((64, raycast.NUM_STATS), np.int32)
    counts[:32, raycast.STAT_NEWTON_WALK] = 2  # a block that works alike: 1
    counts[32, raycast.STAT_NEWTON_WALK] = 32  # one ray of 32 does all: 32
    out = work_counts(raycast, counts)
    assert out["rays"] == 64
    assert out["newton_walk"]["per_ray"] == pytest.approx((64 + 32) / 64)
    assert out["newton_walk"]["divergence"] == pytest.approx((1 + 32) / 2)
    assert out["bvh_candidates"]["divergence"] == 1.0  # no work anywhere


def test_regrouping_changes_no_pixel_or_count_and_fills_the_warps():
    """Regrouping the list of rays before each search and traverse (the rays that search, then
    by element, then those done) leaves every pixel and every ray's work as it was, raises the
    share of each 32-lane group's lanes that work in those launches, and evens the walk's work
    across a group's lanes (hump3D; on the CPU the list is in pixel order before it, where a
    GPU's atomic compaction leaves it in any order)."""
    scene = wc.SCENES["hump3D"]
    if wc.missing_files(scene):
        pytest.skip(f"data file {', '.join(wc.missing_files(scene))} not found")
    mesh = scene.load()
    lo, hi = np.percentile(mesh.field_samples(4), [2, 98])
    tf = wc.tents(lo, hi, wc.COLORS, 12.0 / wc.diagonal(mesh))
    camera = wc.framing(mesh, 48, 27)
    res = {regroup: Renderer(mesh, "cpu", regroup=regroup).render(camera, tf, BACKGROUND, RenderOptions(device="cpu"),
                                                                     ray_counts=True)
           for regroup in (False, True)}
    assert np.array_equal(res[False].rgba, res[True].rgba)
    assert np.array_equal(res[False].ray_counts, res[True].ray_counts)
    before, after = res[False].stats["lane_occupancy"], res[True].stats["lane_occupancy"]
    assert after["search"] > before["search"] and after["traverse"] > before["traverse"]
    assert 1.0 <= after["traverse_divergence"] < before["traverse_divergence"]
