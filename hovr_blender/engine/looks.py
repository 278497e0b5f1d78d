"""The looks a volume can be given, one home for Blender (File > Import, Look > Presets, Fit to Data
Range: ui/) and the command line (`hovr render FILE`, `hovr view FILE`: engine/first_view.py): the
fixed ramps (TF_PRESETS), the looks chosen from the field's sampled values (FIRST_LOOKS), the
field's sampled values themselves (field_samples) and the value range fitted to them (value_range).
A look is ramp stops [(position 0..1, (r, g, b, alpha))] over Value Min..Max, colours scene-linear,
and a Density across the volume (engine/first_view.density_per_world_unit)."""
from __future__ import annotations

import numpy as np

# a new transfer function's Density (across the volume): Blender's property default too
DEFAULT_DENSITY = 4.0

# Transfer-function presets: (name, description, [(ramp position, (r, g, b, alpha))]).
# Colours are scene-linear; alpha x density scale is the extinction.
def _tents(spec, width):
    stops = [(0.0, (0.0, 0.0, 0.0, 0.0)), (1.0, (0.0, 0.0, 0.0, 0.0))]
    for centre, rgb in spec:
        stops += [(centre - width, (*rgb, 0.0)), (centre, (*rgb, 1.0)), (centre + width, (*rgb, 0.0))]
    return sorted(stops, key=lambda s: s[0])


DEFAULT_PRESET = "SMOOTH"  # a new transfer function's ramp: shows any field once its range is fitted
TF_PRESETS = {
    "TENTS": ("Three Tents", "Three thin coloured tents (isosurface-like shells)",
              _tents(((0.2, (1.0, 0.2, 0.1)), (0.5, (0.1, 1.0, 0.2)), (0.8, (0.2, 0.3, 1.0))), 0.04)),
    "SPIKES": ("Spikes", "Four narrow spikes, the style of the paper's figures",
               _tents(((0.2, (1.0, 0.1, 0.1)), (0.4, (1.0, 1.0, 0.1)), (0.6, (0.1, 1.0, 0.1)), (0.8, (0.1, 0.3, 1.0))), 0.01)),
    "SMOOTH": ("Smooth Ramp", "Blue to red, opacity rising with the value",
               [(0.0, (0.05, 0.1, 1.0, 0.0)), (0.5, (0.2, 1.0, 0.3, 0.3)), (1.0, (1.0, 0.1, 0.05, 1.0))]),
    "GREY": ("Grey Fog", "Uniform grey fog, denser for larger values",
             [(0.0, (0.8, 0.8, 0.8, 0.0)), (1.0, (0.8, 0.8, 0.8, 1.0))]),
}


# Looks chosen from the data (issue 30): ramp stops placed by the field's sampled distribution,
# so a first picture shows where the values lie rather than a fog over the range's extremes. Each
# is name -> (label, description, look(values, value_min, value_max) -> (stops, density across
# the volume)); the comparison of these and TF_PRESETS' smooth ramp on the shared datasets is
# scripts/first_pictures.py looks (docs/user-guide.md shows it).
# ParaView's Cool to Warm: sRGB (0.231, 0.298, 0.753), (0.865, 0.865, 0.865), (0.706, 0.016, 0.150), here linear
COOL_TO_WARM = ((0.0, (0.0436, 0.0723, 0.5272)), (0.5, (0.7199, 0.7199, 0.7199)), (1.0, (0.4566, 0.0012, 0.0196)))


def _cool_to_warm(t: float) -> tuple:
    """ParaView's Cool to Warm map at t in [0, 1], scene-linear RGB (piecewise linear between its
    three stops here; ParaView interpolates in Msh space, near enough for a legend-true ramp)."""
    t = float(np.clip(t, 0.0, 1.0))
    (a, ca), (_, cm), (_, cb) = COOL_TO_WARM
    lo, hi, u = (ca, cm, t / 0.5) if t <= 0.5 else (cm, cb, (t - 0.5) / 0.5)
    return tuple(float(x + u * (y - x)) for x, y in zip(lo, hi))


def quantiles(values, qs, weights=None) -> np.ndarray:
    """The values' quantiles `qs`; with `weights` (the volume each value stands for:
    field_samples(..., weights=True)), quantiles over the volume rather than over the samples."""
    values = np.asarray(values, dtype=np.float64)
    if weights is None:
        return np.quantile(values, qs)
    order = np.argsort(values, kind="stable")
    w = np.asarray(weights, dtype=np.float64)[order]
    cum = np.cumsum(w)
    return np.interp(np.asarray(qs, dtype=np.float64) * cum[-1], cum - 0.5 * w, values[order])


def ramp_positions(values, value_min: float, value_max: float, qs, weights=None) -> np.ndarray:
    """The ramp positions (0..1 over Value Min..Max) of the values' quantiles `qs` (quantiles)."""
    return np.clip((quantiles(values, qs, weights) - value_min) / (value_max - value_min), 0.0, 1.0)


# The narrowest ramp feature a look from the data makes: float32 resolves it on fields whose
# rounding is up to 1e-6 of their range (field_frame.RESOLUTION), hump3D's rho (4.7e-7) among them.
LOOK_MIN_GAP = 0.01


def _tents_at(centres, colours, peaks, spacing_share: float, max_width: float, widths=None,
              min_width: float = LOOK_MIN_GAP):
    """Tents (alpha `peaks`) at ramp positions `centres`, each as wide as a share of the gap to its
    neighbours (so tents never overlap; narrower where `widths` asks) and between `min_width` and
    `max_width`, alpha 0 elsewhere. A tent that crosses an end of the ramp is cut there (the stop
    keeps the tent's value), one whose peak is within half its width of an end peaks at the end."""
    c = np.asarray(centres, dtype=np.float64)
    gaps = np.diff(np.concatenate([[c[0] - 2 * max_width], c, [c[-1] + 2 * max_width]]))
    widths = np.minimum(spacing_share * np.minimum(gaps[:-1], gaps[1:]), np.inf if widths is None else widths)
    widths = np.clip(widths, min_width, max_width)
    stops = []
    for x, w, rgb, peak in zip(c, widths, colours, peaks):
        x = 0.0 if x < 0.5 * w else 1.0 if x > 1.0 - 0.5 * w else float(x)
        for p, a in ((x - w, 0.0), (x, peak), (x + w, 0.0)):
            if p != x and not 0.0 <= p <= 1.0:  # cut at the end: the tent's own value there
                p = min(max(p, 0.0), 1.0)
                a = peak * (1.0 - abs(p - x) / w)
            if 0.0 <= p <= 1.0:
                stops.append((p, (*rgb, a)))
    if stops[0][0] > 0.0:
        stops.insert(0, (0.0, (*stops[0][1][:3], 0.0)))
    if stops[-1][0] < 1.0:
        stops.append((1.0, (*stops[-1][1][:3], 0.0)))
    return _monotone(stops)


def _monotone(stops, min_gap: float = LOOK_MIN_GAP):
    """Stops sorted by position, at least `min_gap` apart (a ramp's stops closer than that would be
    a feature float32 cannot resolve): of stops closer, the more opaque one is kept (where
    quantiles coincide: a field of few distinct values); the ends stay at 0 and 1."""
    out = []
    for pos, rgba in sorted(stops, key=lambda st: st[0]):
        stop = (float(pos), tuple(float(v) for v in rgba))
        if out and pos - out[-1][0] < min_gap:
            if rgba[3] > out[-1][1][3]:
                out[-1] = (out[-1][0], stop[1])
            continue
        out.append(stop)
    if out[-1][0] < 1.0 and len(out) > 1 and 1.0 - out[-1][0] < min_gap:
        out[-1] = (1.0, out[-1][1])
    return out


# a quantile shell holds the values within this share of the volume either side of its quantile,
# and is at least SHELL_MIN_WIDTH of the ramp wide: float32 resolves it on fields whose rounding is
# up to 2.5e-6 of their range (PyFR's Taylor-Green density: 1.5e-6)
SHELL_SHARE = 0.03
SHELL_MIN_WIDTH = 0.025


def _volume_share(values, weights, lo: float, hi: float) -> float:
    """The share of the volume (of the samples, without weights) whose values lie in [lo, hi]."""
    inside = (values >= lo) & (values <= hi)
    return float(inside.mean() if weights is None else weights[inside].sum() / weights.sum())


def look_quantile_tents(values, value_min, value_max, weights=None):
    """Three shells at the 10, 50 and 90 % quantiles of the field over the volume (cool, neutral,
    warm), each as thick as the 3 % of the volume either side of it; the two lower half as opaque,
    so the outer ones show what they wrap. A shell that still holds more of the volume (its tent at
    the narrowest float32 resolves, on a plateau of nearly equal values: hump3D's free stream) is
    fainter in proportion, so it is no fog that hides the rest."""
    values = np.asarray(values, dtype=np.float64)
    qs = np.array([0.1, 0.5, 0.9])
    centres = ramp_positions(values, value_min, value_max, qs, weights)
    lower = ramp_positions(values, value_min, value_max, qs - SHELL_SHARE, weights)
    upper = ramp_positions(values, value_min, value_max, qs + SHELL_SHARE, weights)
    stops = _tents_at(centres, [_cool_to_warm(q) for q in qs], (0.5, 0.5, 1.0), 0.4, 0.06,
                      widths=0.5 * (upper - lower), min_width=SHELL_MIN_WIDTH)
    peaks = [k for k, (_, rgba) in enumerate(stops) if rgba[3] > 0 and
             all(rgba[3] >= stops[j][1][3] for j in (max(k - 1, 0), min(k + 1, len(stops) - 1)))]
    for k in peaks:
        a, b = stops[max(k - 1, 0)][0], stops[min(k + 1, len(stops) - 1)][0]
        span = value_max - value_min
        share = _volume_share(values, weights, value_min + a * span, value_min + b * span)
        fade = min(1.0, 2 * SHELL_SHARE / share) if share > 0 else 1.0
        p, rgba = stops[k]
        stops[k] = (p, (*rgba[:3], rgba[3] * fade))
    return stops, 40.0


def look_median_shell(values, value_min, value_max, weights=None):
    """One thin tent at the median over the volume: an isosurface-like shell through the middle of
    the values."""
    (centre,) = ramp_positions(values, value_min, value_max, (0.5,), weights)
    return _tents_at([centre], [(1.0, 0.45, 0.1)], (1.0,), 0.4, 0.03), 24.0


def look_rising(values, value_min, value_max, weights=None):
    """ParaView's default: Cool to Warm, opacity rising linearly from Value Min to Value Max."""
    return [(t, (*_cool_to_warm(t), t)) for t in (0.0, 0.5, 1.0)], 4.0


def look_quantile_ramp(values, value_min, value_max, weights=None):
    """Opacity rising with the value's quantile over the volume (the ramp equalised over the
    values): Cool to Warm by quantile, alpha the quantile squared, so the largest tenth of the
    values is the densest wherever the range's extremes lie."""
    qs = np.array([0.0, 0.25, 0.5, 0.75, 0.9, 0.97, 1.0])
    pos = ramp_positions(values, value_min, value_max, qs, weights)
    return _monotone([(x, (*_cool_to_warm(q), q * q)) for x, q in zip(pos, qs)]), 6.0


def look_smooth(values, value_min, value_max, weights=None):
    """Today's look before issue 30: TF_PRESETS' smooth ramp at Density 4, whatever the data."""
    return TF_PRESETS["SMOOTH"][2], 4.0


FIRST_LOOK = "QUANTILE_TENTS"  # an import's look (with Fit Value Range): chosen on the six shared datasets
FIRST_LOOKS = {
    "SMOOTH": ("Smooth Ramp", look_smooth.__doc__, look_smooth),
    "RISING": ("Rising Opacity", look_rising.__doc__, look_rising),
    "QUANTILE_RAMP": ("Quantile Ramp", look_quantile_ramp.__doc__, look_quantile_ramp),
    "QUANTILE_TENTS": ("Quantile Tents", look_quantile_tents.__doc__, look_quantile_tents),
    "MEDIAN_SHELL": ("Median Shell", look_median_shell.__doc__, look_median_shell),
}


def sample_lattice(mesh, max_values: int = 200_000) -> int:
    """field_samples' lattice: points per axis of an element, ~max_values in all (2..9)."""
    return int(np.clip(np.cbrt(max_values / max(mesh.num_elements, 1)), 2, 9))


def sampled_ranges(mesh) -> list[tuple[float, float]]:
    """(least, greatest) of field_samples' values per volume (VolumeMesh.volume): the field's range
    over the data, as the import's Fit Value Range sees it (within the certified bounds)."""
    from .mesh import element_volumes

    lo, hi = mesh.element_sample_ranges(sample_lattice(mesh))
    true_range = getattr(mesh, "true_range", None)
    if true_range is not None:
        lo, hi = np.clip(lo, *true_range), np.clip(hi, *true_range)
    volume = element_volumes(mesh)
    return [(float(np.nanmin(lo[volume == k])), float(np.nanmax(hi[volume == k])))
            for k in range(int(volume.max()) + 1)]


def field_samples(mesh, samples_per_axis: int | None = None, max_values: int = 200_000, weights: bool = False):
    """Field values on a lattice of reference points inside every element (for the value range,
    the histogram and the looks); the lattice shrinks for big meshes to keep this under
    ~max_values. weights=True: (values, the volume each stands for), for quantiles over the
    volume (fine elements near a wall would otherwise outnumber the rest)."""
    if samples_per_axis is None:
        samples_per_axis = sample_lattice(mesh, max_values)
    values = mesh.field_samples(samples_per_axis)
    finite = np.isfinite(values)
    values = values[finite]
    true_range = getattr(mesh, "true_range", None)  # a fitted derived field's exact range (io/magnitude.py)
    if true_range is not None:
        values = np.clip(values, *true_range)
    return (values, mesh.field_sample_weights(samples_per_axis)[finite]) if weights else values


# A field varies by less than this, relative to its magnitude, only by rounding: it is constant.
ROUNDING_RELATIVE = 1e-12
# Values all within this of zero are rounding around zero (a zero field computed in float64).
ROUNDING_ZERO = 1e-12


def _float32_distinct(lo: float, hi: float) -> tuple[float, float]:
    """(lo, hi) widened to the nearest float32 values apart: Value Min/Max are float32 properties."""
    lo32, hi32 = np.float32(lo), np.float32(hi)
    if hi32 > lo32:
        return lo, hi
    return float(np.nextafter(lo32, np.float32(-np.inf))), float(np.nextafter(hi32, np.float32(np.inf)))


def value_range(values) -> tuple[float, float, str | None]:
    """(Value Min, Value Max, warning or None) for sampled field values. A field constant up to
    rounding (its spread below ROUNDING_RELATIVE of its magnitude, or every value within
    ROUNDING_ZERO of zero) gets a range centred on its value, with a warning in words, rather than
    a ramp stretched over its round-off; a range float32 cannot tell apart is widened until it can."""
    values = np.asarray(values, dtype=np.float64)
    lo, hi = float(values.min()), float(values.max())
    magnitude = max(abs(lo), abs(hi))
    if magnitude <= ROUNDING_ZERO:
        return -1.0, 1.0, (f"the field is zero up to rounding (every value within \u00b1{magnitude:.2g}): Value "
                           "Min/Max set to -1..1, so it shows as one uniform value; set them by hand if values this "
                           "small are the data")
    if hi - lo <= ROUNDING_RELATIVE * magnitude:
        centre = 0.5 * (lo + hi)
        half = 0.5 * abs(centre)
        what = "constant" if hi == lo else f"constant up to rounding (spread {hi - lo:.2g})"
        return centre - half, centre + half, (f"the field is {what}: {centre:.6g} everywhere; Value Min/Max set "
                                              f"around it ({centre - half:.4g}..{centre + half:.4g})")
    lo, hi = _float32_distinct(lo, hi)
    return lo, hi, None
