"""The ray kernels: render contract §3-4, one thread per pixel of a tile, in rounds; this module is
what the host (engine/renderer.py) takes of them: the kernels as handles (kernel_table, the one list),
the walk's kernels specialised per mesh (walk_kernels), and the structs and counters they share.

A render of a tile runs init_rays once (kernels/rays.py), then rounds of
1. search (kernels/entry.py): rays that are not inside a known element find the element they
   enter next: the first face crossing beyond their t that enters one (kernels/crossing.py: the
   BVH over the boxes of every element face's triangles, Newton on the curved face);
2. traverse (kernels/walk.py): each ray walks front to back through shared faces and writes up to
   SEGMENTS_PER_ROUND element segments, until it needs a search again; sample, refine and
   coefficients fill in each segment's samples and Chebyshev series;
3. integrate (kernels/integrate.py): each ray integrates its segments (kernels/quadrature.py) into
   colour, transmittance, depth and error, and puts itself on the next round's list if it is not
   done (step_terms before it: classified's own step);
until no ray is left, then finalize writes the pixels. Rounds run over the list of rays still
going (no thread is spent on a finished ray), regrouped between rounds (regroup_keys: the rays
that search side by side, then the rays of one element). Separate kernels keep each small: the search (BVH,
polishing face crossings), the walk (Newton, element evaluation) and the quadrature never hold
their registers at the same time, and each compiles quickly.

A trace (Renderer.trace) runs the same rounds with trace_reserve and trace_write in place of
integrate (kernels/cache.py): every segment of every ray, with its series, goes into a
SegmentCache, and the shade kernel later integrates a ray's cached segments through any transfer
function as integrate would have, then writes its pixel.

A look with isosurfaces or cut planes (contract §7) takes integrate and shade in their variant
for them (integrate_kernels; kernels/isosurface.py); a mesh whose field is derived (contract §8)
takes the sample kernel's variant that samples it (kernels/derived.py).

docs/traversal.md: the traversal's invariant and its work counts (kernels/args.py STAT_*).
"""
from __future__ import annotations

from dataclasses import dataclass, fields

# what the host reads of the kernels besides the table: the structs, counters, sizes and the
# derived fields' operation ids (kernels/derived.py)
from .args import (MAX_SAMPLES, NUM_STATS, SEGMENTS_PER_ROUND, STAT_BVH_CANDIDATES, STAT_EMPTY, STAT_FIELD_EVALS,
                   STAT_LOCATES, STAT_NEWTON_SAMPLE, STAT_NEWTON_SEARCH, STAT_NEWTON_WALK, STAT_PIECEWISE,
                   STAT_RESTRICTION_EVALS, STAT_ROUNDS, STAT_SEGMENTS, STAT_SMOOTH, STAT_WALKS, CameraArgs, DerivedArgs,
                   MeshArgs, QuadArgs, RayState, SegmentCache, Segments, SurfaceArgs, TransferArgs)
from .cache import make_shade_kernel, sum_counts, trace_ends, trace_reserve, trace_write
from .derived import FIELD, OPERATION_IDS, PER_DENSITY
from .entry import make_search_kernel
from .integrate import finalize, make_integrate_kernel, step_terms
from .rays import camera_ray, init_rays, regroup_keys
from .walk import coefficients, make_sample_kernel, make_traverse_kernel, pyramid_piece_end, refine

# The kernels as handles (KernelTable), the one list: the renderer names each at its launch
# (launch(table.search, ...)), loads a render's, a trace's and a shade's (their *_kernels), and
# times them by their field names.


@dataclass(frozen=True)
class KernelTable:
    """Every kernel of a render, a trace and a shade, the walk's specialised for a mesh and integrate
    and shade for a look (kernel_table)."""

    init_rays: object
    search: object
    traverse: object
    sample: object
    refine: object
    coefficients: object
    step_terms: object
    integrate: object
    regroup_keys: object
    finalize: object
    trace_reserve: object
    trace_write: object
    trace_ends: object
    shade: object
    sum_counts: object

    def render_kernels(self) -> tuple:
        """What Renderer.render launches."""
        return (self.init_rays, self.search, self.traverse, self.sample, self.refine, self.coefficients,
                self.step_terms, self.integrate, self.regroup_keys, self.finalize)

    def trace_kernels(self) -> tuple:
        """What Renderer.trace launches."""
        return (self.init_rays, self.search, self.traverse, self.sample, self.refine, self.coefficients,
                self.trace_reserve, self.trace_write, self.regroup_keys, self.trace_ends)

    def shade_kernels(self) -> tuple:
        """What Renderer.shade launches."""
        return (self.shade, self.sum_counts)

    def named(self) -> dict:
        """{field name: kernel}: every kernel by the name the stats and reports give it."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


_WALK = {}
_SAMPLE = {}
_INTEGRATE = {}


def walk_kernels(curved: bool, modes: int = 0, derived: bool = False):
    """(search, traverse, sample), specialised at compile time: with `curved` False the Newton
    location and curved sampling are compiled out (affine meshes pay only for what they use);
    with `modes` N > 0 (element.static_modes of the mesh) the sample kernel evaluates
    hexahedra and prisms of N modes unrolled; with `derived` it samples the mesh's derived
    field (MeshArgs.derived) instead of its own."""
    key = bool(curved)
    if key not in _WALK:
        _WALK[key] = (make_search_kernel(key), make_traverse_kernel(key))
    skey = (key, int(modes), bool(derived))
    if skey not in _SAMPLE:
        _SAMPLE[skey] = make_sample_kernel(*skey)
    return _WALK[key] + (_SAMPLE[skey],)


def integrate_kernels(isosurfaces: bool = False):
    """(integrate, shade), specialised at compile time: with `isosurfaces` False (a look without
    isosurfaces or planes) the root finding and the surface points are compiled out."""
    key = bool(isosurfaces)
    if key not in _INTEGRATE:
        _INTEGRATE[key] = (make_integrate_kernel(key), make_shade_kernel(key))
    return _INTEGRATE[key]


def kernel_table(curved: bool, modes: int = 0, derived: bool = False, isosurfaces: bool = False) -> KernelTable:
    """The KernelTable, the walk's kernels specialised as walk_kernels(curved, modes, derived) (the
    renderer's KernelVariant), integrate and shade as integrate_kernels(isosurfaces)."""
    search, traverse, sample = walk_kernels(curved, modes, derived)
    integrate, shade = integrate_kernels(isosurfaces)
    return KernelTable(init_rays=init_rays, search=search, traverse=traverse, sample=sample, refine=refine,
                       coefficients=coefficients, step_terms=step_terms, integrate=integrate,
                       regroup_keys=regroup_keys, finalize=finalize, trace_reserve=trace_reserve,
                       trace_write=trace_write, trace_ends=trace_ends, shade=shade, sum_counts=sum_counts)
