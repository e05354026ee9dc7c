"""A scan's checks: refusals before it casts, and warnings for what it may not mean.

Refusals (:class:`~treesim.errors.TreesimError`): a scan needing more rays than
``max_rays`` (:func:`check_ray_limit`, with an estimate of its time) and a station inside
the geometry (:func:`check_inside`).

Warnings: a scan that runs but may not be what was meant says so in
``ScanResult.warnings`` (and the summary's ``warnings``): a station on a surface or
enclosed by a mesh whose normals face it (:func:`station_warnings`), and triangles lost
to precision (zero area in float64 as given, or distorted in float32 around the local
frame, which Open3D casts in: :func:`precision_warnings`).
"""

from __future__ import annotations

import numpy as np

from .._system import cpu_count
from ..cloud import LABEL_NAMES
from ..errors import ResourceLimitError, ScanError
from ..params import ScannerSpec
from ..scene import Scene
from .caster import DISTORTED_SHARE, Caster
from .humanize import human_time
from .stations import Station

#: Rays Open3D casts per second per core on this kind of machine (measured, hits and
#: misses mixed); used only for the estimate printed when a scan is refused.
_EST_RAYS_PER_S = 2.0e6
#: Share of a scene's triangles lost to precision (zero area in float64, or distorted in
#: float32) from which a scan warns: a few degenerate triangles are common and harmless.
DEGENERATE_WARN_FRACTION = 0.01
#: Share of the 26 directions around a station that must cross the geometry an odd
#: number of times for it to count as enclosed (a few rays through shared edges or
#: vertices can miscount).
ENCLOSED_FRACTION = 0.9


def check_ray_limit(
    upper: int, n_stations: int, spec: ScannerSpec, max_rays: int | None, nthreads: int
) -> None:
    """Refuse (:class:`~treesim.errors.ResourceLimitError`) a scan whose ``upper`` rays (its
    windows' pulses with every sub-ray, an upper bound) exceed ``max_rays`` (None: no
    limit), saying how long it would take here."""
    s = spec.rays_per_pulse
    if max_rays is not None and upper > max_rays:
        secs = upper / (_EST_RAYS_PER_S * max(1, nthreads or cpu_count()))
        raise ResourceLimitError(
            f"this scan needs {upper:.3g} rays at most ({n_stations} station"
            f"{'s' if n_stations > 1 else ''} at "
            f"{spec.horizontal_resolution_deg}°×{spec.vertical_resolution_deg}°"
            f"{f', {s} sub-rays per pulse' if s > 1 else ''}), about "
            f"{human_time(secs)} here, over the limit of {max_rays:.3g}; coarsen the "
            "resolution or raise max_rays (--max-rays); memory stays bounded either way"
        )


#: 26 unit directions: to the faces, edges and corners of a cube around a station.
_AROUND = np.array(
    [
        [x, y, z]
        for x in (-1, 0, 1)
        for y in (-1, 0, 1)
        for z in (-1, 0, 1)
        if (x, y, z) != (0, 0, 0)
    ],
    dtype=np.float64,
)
_AROUND /= np.linalg.norm(_AROUND, axis=1, keepdims=True)


def _where(k: int, st: Station) -> str:
    return f"station {k} at {tuple(round(c, 3) for c in st.position_m)}"


def check_inside(caster: Caster, o: np.ndarray, k: int, st: Station) -> None:
    """Refuse (:class:`~treesim.errors.ScanError`) station ``st`` (index ``k``, at ``o`` in
    the local frame) when it stands inside the geometry: nine in ten of the rays in 26
    directions hit, and nine in ten of those hit a surface from behind."""
    g = _AROUND
    t, prim = caster.cast(o, g)
    hit = prim >= 0
    if hit.sum() < 0.9 * len(g):
        return
    back = np.einsum("ij,ij->i", g[hit], caster.normal[prim[hit]]) > 0
    if back.mean() >= 0.9:
        label = LABEL_NAMES[int(np.bincount(caster.label[prim[hit]]).argmax())]
        raise ScanError(
            f"{_where(k, st)} is inside the {label} geometry (nearest surface "
            f"{t[hit].min():.3f} m away in every direction); move it outside the mesh"
        )


def station_warnings(caster: Caster, o: np.ndarray, k: int, st: Station) -> list[str]:
    """What is wrong with a station that :func:`check_inside` lets through: it stands
    on a surface (within a few float32 steps at its position, at least 1 µm), where
    rays leave from both sides of it; or it is enclosed by geometry whose surfaces face
    it (inverted normals), by the parity of crossings in 26 directions."""
    o3c = caster.o3d.core
    q = o3c.Tensor(o[None, :].astype(np.float32))
    near = caster.rc.compute_closest_points(q, nthreads=caster.nthreads)
    d = float(np.linalg.norm(near["points"].numpy()[0].astype(np.float64) - o))
    tol_m = max(4.0 * float(np.spacing(np.float32(np.abs(o).max()))), 1e-6)
    label = LABEL_NAMES[int(caster.label[int(near["primitive_ids"].numpy()[0])])]
    if d <= tol_m:
        return [
            f"{_where(k, st)} is on a {label} surface ({d * 1e3:.2g} mm from it, within "
            f"float32 precision {tol_m * 1e3:.2g} mm): rays that start on a surface see "
            "both of its sides and may record the inside of the mesh; move the station "
            "off the surface"
        ]
    rays = np.empty((len(_AROUND), 6), dtype=np.float32)
    rays[:, :3] = o
    rays[:, 3:] = _AROUND
    crossings = caster.rc.count_intersections(o3c.Tensor(rays), nthreads=caster.nthreads)
    odd = int((crossings.numpy() % 2 == 1).sum())
    if odd >= ENCLOSED_FRACTION * len(_AROUND):
        return [
            f"{_where(k, st)} looks enclosed by the {label} geometry: {odd} of "
            f"{len(_AROUND)} rays from it cross the mesh an odd number of times, though the "
            "surfaces around it face it (are the mesh's normals inverted?); the scan "
            "records the inside of the mesh"
        ]
    return []


def precision_warnings(scene: Scene, caster: Caster | None, radius_m: float) -> list[str]:
    """Triangles lost to precision: zero area in float64 as given (dropped by the
    scene), or in float32 around the local frame (kept, but rays miss them)."""
    out = []
    total = scene.n_triangles + scene.dropped_degenerate
    if scene.dropped_degenerate >= DEGENERATE_WARN_FRACTION * total:
        big = float(np.abs(scene.used_vertices).max())
        out.append(
            f"{scene.dropped_degenerate:,} of {total:,} triangles "
            f"({scene.dropped_degenerate / total:.1%}) have no area in float64 and were "
            f"dropped: coordinates reach {big:.3g} m, where float64 steps are "
            f"{float(np.spacing(big)):.2g} m; move the mesh near the origin before export"
        )
    if caster is not None and caster.distorted >= DEGENERATE_WARN_FRACTION * len(caster.faces):
        n = len(caster.faces)
        out.append(
            f"{caster.distorted:,} of {n:,} triangles ({caster.distorted / n:.1%}) are "
            f"distorted in float32, the precision rays are cast in (vertices move by up to "
            f"{caster.moved_m:.2g} m, more than {DISTORTED_SHARE:g} of those triangles' "
            f"shortest edge): the scene reaches {radius_m:.3g} m from its centre; rays may "
            "miss or hit the wrong triangles, so scan distant parts of the scene separately"
        )
    return out
