"""Wind: how a tree's parts sway while it is scanned, and the tree posed at any time.

The model (linear, first modes only, modal superposition)
---------------------------------------------------------
A tree with a cylinder table (a QSM, a procedural tree) is a set of *branches* (the
table's ``branch`` ids; the stem is the branch with no parent), each a cantilever
clamped on its parent. Each branch ``b`` sways in its first bending mode: the axis point
at arc length ``s`` moves by ``q_b(t) φ(s / L_b)``, ``q_b`` the tip displacement (two
components perpendicular to the branch's base-to-tip direction), ``φ`` the first mode
shape of a uniform cantilever (``φ(0) = 0``, ``φ(1) = 1``). A branch's base moves with
its parent at the point where it is attached, and so on down to the stem's base, which
stands still: a point's displacement is its own branch's term plus its parent's at the
attachment point, and so on (translations only: the parent's rotation at the
attachment, of order slope × branch length, is left out). Cross-sections translate
with their axis point; every mesh vertex follows the cylinder it lies on (wood) or the
cylinder nearest to it (leaves follow the stem they grow on; :func:`assign_vertices`).

* **Stem frequency.** ``f = a · DBH / H²`` (DBH and height in m), the relation Moore &
  Maguire (2004, Trees 18: 195-203) found across 602 conifers of eight species (pines
  lower than spruces and Douglas-fir; de-branched stems higher). Their fitted slope
  could not be consulted here: ``a = 350 m/s`` (:data:`STEM_FREQUENCY_COEFF`; 3.5 Hz per
  cm/m²) is this model's choice, the uniform-cantilever value ``0.14 √(E/ρ) ≈ 420 m/s``
  lowered for the crown's mass, which gives 0.26 Hz for a 30 cm, 20 m tree, within
  the 0.1-1 Hz their data span. Jackson et al. (2019, J. R. Soc. Interface 16:
  20190116) showed the relation holds for conifers but explains less for broadleaves,
  whose architecture matters, and that leaves lower the frequency and the damping: a
  leaf-on tree's stem frequency is scaled by ``√(M_wood / (M_wood + M_leaf))``.
* **Branch frequency.** A uniform circular cantilever: ``f = (1.875² / 2π) (r / 2)
  √(E / ρ) / L²`` (``f ∝ r / L²``), ``r`` the branch's length-weighted mean radius,
  scaled by ``√(m_own / m_eff)`` for the mass its children and leaves add (James 2014,
  Arboric. Urban For. 40: 125-134, measured branches of an open-grown tree swaying as
  coupled cantilevers on the trunk, each with a frequency of its own; the formula is
  the beam's, not fitted to his data). ``E / ρ`` of green wood: 8 GPa / 900 kg/m³.
* **Damping.** Ratio 0.1 for stems and branches (:data:`DAMPING_RATIO`): Moore &
  Maguire (2004) give internal damping under 0.05 plus aerodynamic damping; their
  Douglas-firs with crowns damp at 0.08 to near critical. One value, not fitted.
* **Forcing.** Wind speed ``U`` along ``wind_direction_deg`` (horizontal), with
  along-wind and lateral turbulence of von Kármán spectra (ESDU 85020 forms; intensity
  ``wind_turbulence_intensity``, lateral σ = 0.75 of the along-wind one, integral
  length :data:`TURBULENCE_LENGTH_M`), fully coherent over the tree (it is smaller
  than the gusts), drawn as a sum of :data:`N_COMPONENTS` sinusoids with seeded random
  phases (``numpy.random.default_rng(wind_seed)``: the same seed, the same motion).
  Drag ``½ ρ_air C_d A U²`` on each part's frontal area (wood: ``2 r L`` times the
  sine of its angle to the wind, ``C_d`` 1.0; leaves: half their one-sided area,
  ``C_d`` 0.5, as flexible leaves reconfigure), linearised: mean ``∝ U²``, fluctuation
  ``∝ 2 U u'`` along the wind and ``U v'`` across it. A branch's tip deflects under
  the mean drag as a tapered cantilever does (the bending moment of its own parts' drag
  and its children's, at their attachments, over ``E I`` of each cylinder, integrated to
  the tip); the fluctuations pass through a damped oscillator at the branch's frequency,
  ``H(f) = 1 / (1 - r² + 2iζr)``, ``r = f / f_branch``. Thin twigs under heavy leaves
  would bend beyond linear theory: a branch's own motion (mean + 3σ) is scaled down to
  :data:`MAX_DEFLECTION` of its length.
* **Deterministic forcing** (:meth:`SwayModel.sinusoid`): the stem alone sways as
  ``A sin(2π f t + phase)`` along the wind (the analytic test case).

What is simplified: first modes only (no higher modes; a parent's motion carries its
children but does not excite them), the stiffness from statics and the frequency from
the measured relations (not one consistent beam model), linear drag about the mean, no
Vogel reconfiguration exponent, no crown collisions, lateral turbulence acting only
through drag, full coherence over the crown, the time of station ``k`` offset by
``k × (scan duration + STATION_GAP_S)`` so stations see different gusts. Checked
against one measurement in kind and order of magnitude, not calibrated: Vaaja et al.
(2016, ISPRS Annals III-8: 117-123), a pine's stem slabs at 3 and 9 m/s
(``benchmarks/bench_wind_stem.py``, docs/commands/sweep.md): the same signs of diameter
error and their growth with height; at 9 m/s an exposed tree's stem diameters leave
the still scan's from 17-41 % of its height (three gust seeds), around their ~28 %.

Casting a moving tree (:func:`treesim.scan.scan`)
-------------------------------------------------
Each station's pulses are cast in time slices, each against the tree posed at the
slice's mid time (:class:`MovingScene`): runs of whole mirror cycles (a column; with a
two-sided mirror also the column opposite) when a slice lasts a cycle or more, else
runs of lines of one column. A slice lasts as long as the tree's motion within it stays
under ``slice_fraction`` (0.25) of the point spacing at the nearest range the tree can
come to (:func:`slice_duration_s`, from each branch's 3σ speed and swing, its
ancestors' added). A slice's ray-casting scene holds only the triangles its columns
can meet in that pose (:class:`Sectors`, from each vertex's motion in the poses cast:
exact, not statistical), posed in float64 and cast through a caster of their own, with
the still path's float64 refinement. Each point carries ``wind_displacement_m``: how
far the hit surface was from its rest pose (float64 m, a magnitude: the wind's share of
the point's error in one number, comparable with range noise; the direction is the
wind's for stems and along-wind branches).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..cloud import LABEL_CODES
from ..errors import InvalidParameterError

#: The per-point field of a windy scan: the hit part's displacement from rest (m).
WIND_FIELD = "wind_displacement_m"
#: Stem frequency slope ``a`` of ``f = a DBH / H²`` (m/s; see the module's notes).
STEM_FREQUENCY_COEFF = 350.0
#: Green wood: Young's modulus over density (m²/s²) and density (kg/m³).
YOUNG_MODULUS_PA = 8.0e9
WOOD_DENSITY_KG_M3 = 900.0
E_OVER_RHO = YOUNG_MODULUS_PA / WOOD_DENSITY_KG_M3
#: Fresh leaf mass per one-sided area (kg/m²).
LEAF_MASS_KG_M2 = 0.2
AIR_DENSITY_KG_M3 = 1.2
DRAG_WOOD = 1.0
DRAG_LEAF = 0.5
DAMPING_RATIO = 0.1
TURBULENCE_LENGTH_M = 20.0
LATERAL_SIGMA_RATIO = 0.75
N_COMPONENTS = 512
#: Forcing frequencies (Hz): from, to.
FORCING_BAND_HZ = (0.005, 30.0)
#: Largest own deflection (mean + 3σ) of a branch, as a share of its length: beyond it
#: linear bending does not hold (thin twigs under heavy leaves); the motion is scaled down.
MAX_DEFLECTION = 0.1
#: Seconds between two stations' scans (moving the scanner), for the wind's clock.
STATION_GAP_S = 300.0
#: First cantilever mode: β L and the shape's σ.
_BETA = 1.8751040687119611
_SIGMA = (math.cosh(_BETA) + math.cos(_BETA)) / (math.sinh(_BETA) + math.sin(_BETA))
#: Mode-shape factor of the uniform cantilever's frequency: β² / 2π × (1/2) (r/2 is the
#: radius of gyration of a disc).
_BEAM_COEFF = _BETA**2 / (2.0 * math.pi) / 2.0


def mode_shape(xi: np.ndarray) -> np.ndarray:
    """First bending mode of a uniform cantilever, ``φ(0) = 0``, ``φ(1) = 1``.

    Parameters
    ----------
    xi : array
        Position along the beam over its length (clipped to [0, 1]).

    Returns
    -------
    array of float64

    Examples
    --------
    >>> mode_shape(np.array([0.0, 0.5, 1.0])).round(4).tolist()
    [0.0, 0.3395, 1.0]
    """
    x = _BETA * np.clip(np.asarray(xi, dtype=np.float64), 0.0, 1.0)
    raw = np.cosh(x) - np.cos(x) - _SIGMA * (np.sinh(x) - np.sin(x))
    return raw / 2.0  # the raw shape is 2 at the tip


@dataclass(frozen=True)
class Cylinders:
    """The columns of a cylinder table the sway model needs (float64, metres).

    ``parent`` is 0-based (-1: none); ``branch`` ids group the rows into branches,
    ordered within a branch by ``position``.
    """

    start: np.ndarray
    axis: np.ndarray
    length_m: np.ndarray
    radius_m: np.ndarray
    end_radius_m: np.ndarray
    parent: np.ndarray
    branch: np.ndarray
    position: np.ndarray

    @property
    def n(self) -> int:
        return len(self.length_m)

    @property
    def end(self) -> np.ndarray:
        return self.start + self.axis * self.length_m[:, None]

    def shifted(self, origin: np.ndarray) -> Cylinders:
        """The same cylinders with ``origin`` subtracted (a local frame)."""
        return Cylinders(
            self.start - np.asarray(origin, dtype=np.float64),
            self.axis,
            self.length_m,
            self.radius_m,
            self.end_radius_m,
            self.parent,
            self.branch,
            self.position,
        )


def cylinders_from(table: Any) -> Cylinders:
    """:class:`Cylinders` from a :class:`treesim.models.CylinderTable` (or any object with
    its ``start``, ``axis``, ``length_m``, ``radius_m``, ``parent``, ``branch`` and
    optional ``end_radius_m`` and ``position_in_branch`` arrays).

    Examples
    --------
    >>> from treesim.models import generate_tree
    >>> cylinders_from(generate_tree("sapling").cylinders).n > 10  # doctest: +SKIP
    True
    """
    if isinstance(table, Cylinders):
        return table
    length = np.asarray(table.length_m, dtype=np.float64)
    radius = np.asarray(table.radius_m, dtype=np.float64)
    axis = np.asarray(table.axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    end_r = getattr(table, "end_radius_m", None)
    pos = getattr(table, "position_in_branch", None)
    return Cylinders(
        start=np.asarray(table.start, dtype=np.float64),
        axis=axis,
        length_m=length,
        radius_m=radius,
        end_radius_m=radius if end_r is None else np.asarray(end_r, dtype=np.float64),
        parent=np.asarray(table.parent, dtype=np.int64),
        branch=np.asarray(table.branch, dtype=np.int64),
        position=np.arange(len(length)) if pos is None else np.asarray(pos, dtype=np.int64),
    )


@dataclass(frozen=True)
class Forcing:
    """The wind a :class:`SwayModel` is driven by (see :meth:`SwayModel.turbulent`)."""

    speed_m_s: float
    direction_deg: float = 0.0
    turbulence_intensity: float = 0.3
    seed: int = 0


class Structure:
    """A cylinder table's branches: arc lengths, parents, attachment points, masses.

    Parameters
    ----------
    cyl : Cylinders
        In the frame the model is posed in (a local frame).
    leaf_area_m2 : (n,) float, optional
        One-sided leaf area carried by each cylinder (:func:`leaf_area_per_cylinder`).
    """

    def __init__(self, cyl: Cylinders, leaf_area_m2: np.ndarray | None = None) -> None:
        self.cyl = cyl
        n = cyl.n
        ids, self.branch_of = np.unique(cyl.branch, return_inverse=True)
        nb = len(ids)
        self.nb = nb
        order = np.lexsort((cyl.position, self.branch_of))
        lengths = cyl.length_m[order]
        cum = np.cumsum(lengths)
        first = np.searchsorted(self.branch_of[order], np.arange(nb))
        before = np.concatenate([[0.0], cum])[first]
        self.s0 = np.empty(n)
        self.s0[order] = cum - lengths - np.repeat(before, np.diff(np.append(first, n)))
        self.length_b = np.bincount(self.branch_of, weights=cyl.length_m, minlength=nb)
        base_row = order[first]
        last_row = order[np.append(first[1:], n) - 1]
        tip = cyl.end[last_row]
        d = tip - cyl.start[base_row]
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        self.axis_b = np.where(norm > 0, d / np.maximum(norm, 1e-300), cyl.axis[base_row])
        prow = cyl.parent[base_row]
        self.parent_b = np.where(prow >= 0, self.branch_of[np.maximum(prow, 0)], -1)
        self.parent_b[self.parent_b == np.arange(nb)] = -1  # a row linked to its own branch
        pr = np.maximum(prow, 0)
        along = np.einsum("ij,ij->i", cyl.start[base_row] - cyl.start[pr], cyl.axis[pr])
        s_att = self.s0[pr] + np.clip(along, 0.0, cyl.length_m[pr])
        pl = self.length_b[np.maximum(self.parent_b, 0)]
        self.xi_attach = np.where(self.parent_b >= 0, s_att / np.maximum(pl, 1e-300), 0.0)
        self.depth = _depths(self.parent_b)
        self.xi_mid = (self.s0 + 0.5 * cyl.length_m) / self.length_b[self.branch_of]
        r0, r1 = cyl.radius_m, cyl.end_radius_m
        self.wood_kg = WOOD_DENSITY_KG_M3 * math.pi * (r0 * r0 + r0 * r1 + r1 * r1) / 3.0
        self.wood_kg = self.wood_kg * cyl.length_m
        self.leaf_m2 = np.zeros(n) if leaf_area_m2 is None else np.asarray(leaf_area_m2, float)
        self.r_mean_b = np.bincount(
            self.branch_of, weights=0.5 * (r0 + r1) * cyl.length_m, minlength=nb
        ) / np.maximum(self.length_b, 1e-300)

    def levels(self, reverse: bool = False) -> list[np.ndarray]:
        """Branch indices by depth (the stem first; ``reverse``: the tips first)."""
        out = [np.flatnonzero(self.depth == d) for d in range(int(self.depth.max()) + 1)]
        return out[::-1] if reverse else out

    def subtree_sum(self, own: np.ndarray) -> np.ndarray:
        """Per branch: ``own`` (per branch) summed over the branch and its descendants."""
        total = own.astype(np.float64).copy()
        for idx in self.levels(reverse=True):
            idx = idx[self.parent_b[idx] >= 0]
            np.add.at(total, self.parent_b[idx], total[idx])
        return total

    def modal_sums(self, per_cyl: np.ndarray, power: int) -> np.ndarray:
        """Per branch: Σ own cylinders' ``per_cyl`` × φ(ξ)^power, plus each child's
        subtree total × φ(ξ at its attachment)^power."""
        phi_c = mode_shape(self.xi_mid) ** power
        own = np.bincount(self.branch_of, weights=per_cyl * phi_c, minlength=self.nb)
        sub = self.subtree_sum(np.bincount(self.branch_of, weights=per_cyl, minlength=self.nb))
        child = np.flatnonzero(self.parent_b >= 0)
        phi_a = mode_shape(self.xi_attach[child]) ** power
        np.add.at(own, self.parent_b[child], sub[child] * phi_a)
        return own

    def stem_size(self) -> tuple[float, float]:
        """DBH (m, at 1.3 m along the stem from its base) and height (m) of the tree."""
        cyl = self.cyl
        roots = np.flatnonzero(self.parent_b < 0)
        stem = roots[np.argmax(self.length_b[roots])]
        rows = np.flatnonzero(self.branch_of == stem)
        base_z = float(cyl.start[:, 2].min())
        top_z = float(max(cyl.start[:, 2].max(), cyl.end[:, 2].max()))
        inside = (self.s0[rows] <= 1.3) & (self.s0[rows] + cyl.length_m[rows] >= 1.3)
        k = rows[inside][0] if inside.any() else rows[np.argmin(self.s0[rows])]
        frac = float(np.clip((1.3 - self.s0[k]) / max(cyl.length_m[k], 1e-300), 0.0, 1.0))
        r = cyl.radius_m[k] + frac * (cyl.end_radius_m[k] - cyl.radius_m[k])
        return 2.0 * float(r), max(top_z - base_z, 1e-3)


def _depths(parent: np.ndarray) -> np.ndarray:
    """Depth of each node of a forest given by ``parent`` (-1: a root)."""
    depth = np.zeros(len(parent), dtype=np.int64)
    node = parent.copy()
    for _ in range(len(parent) + 1):
        live = node >= 0
        if not live.any():
            return depth
        depth[live] += 1
        node[live] = parent[node[live]]
    raise InvalidParameterError("the cylinder table's branches link in a cycle")


def leaf_area_per_cylinder(
    cyl_of_vertex: np.ndarray, vertices: np.ndarray, faces: np.ndarray, n_cyl: int
) -> np.ndarray:
    """One-sided leaf area (m²) each cylinder carries: each leaf triangle's area goes to
    its first corner's cylinder (``cyl_of_vertex``, -1: none)."""
    t = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    owner = cyl_of_vertex[faces[:, 0]]
    ok = owner >= 0
    return np.bincount(owner[ok], weights=area[ok], minlength=n_cyl)


def _von_karman(f_hz: np.ndarray, speed: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided von Kármán spectra (m²/s² per Hz) of along-wind and lateral turbulence
    (ESDU 85020 forms), integral length :data:`TURBULENCE_LENGTH_M`."""
    n = f_hz * TURBULENCE_LENGTH_M / speed
    scale = 4.0 * TURBULENCE_LENGTH_M / speed
    s_u = sigma**2 * scale / (1.0 + 70.8 * n * n) ** (5.0 / 6.0)
    sv2 = (LATERAL_SIGMA_RATIO * sigma) ** 2
    s_v = sv2 * scale * (1.0 + 755.2 * n * n) / (1.0 + 283.2 * n * n) ** (11.0 / 6.0)
    return s_u, s_v


class SwayModel:
    """A tree's sway: each branch's tip displacement at any time, and any point's.

    Build one with :meth:`turbulent` (wind and turbulence) or :meth:`sinusoid` (a
    steady sway of the stem, the analytic case). ``frequency_hz`` (per branch), the
    branch directions ``e_in`` (along the wind, across the branch) and ``e_cross``, the
    mean tip deflection and the complex amplitudes of the components are public.

    Examples
    --------
    >>> from treesim.models import generate_tree
    >>> tree = generate_tree("sapling")  # doctest: +SKIP
    >>> model = SwayModel.turbulent(Structure(cylinders_from(tree.cylinders)),
    ...                             Forcing(speed_m_s=5.0))  # doctest: +SKIP
    >>> model.tips(0.5).shape  # doctest: +SKIP
    (..., 3)
    """

    def __init__(
        self,
        structure: Structure,
        frequency_hz: np.ndarray,
        e_in: np.ndarray,
        e_cross: np.ndarray,
        mean_in_m: np.ndarray,
        comp_hz: np.ndarray,
        q_in: np.ndarray,
        q_cross: np.ndarray,
        description: dict[str, Any],
    ) -> None:
        self.structure = structure
        self.frequency_hz, self.e_in, self.e_cross = frequency_hz, e_in, e_cross
        self.mean_in_m = mean_in_m
        self.omega = 2.0 * math.pi * comp_hz
        self.q_in, self.q_cross = q_in, q_cross
        self.description = description
        amp = np.abs(q_in) + np.abs(q_cross)
        #: hard bound of each branch's own tip motion about rest (m), and of its speed
        self.bound_m = np.abs(mean_in_m) + amp.sum(axis=1)
        hard_v = (amp * self.omega).sum(axis=1)
        power = 0.5 * (np.abs(q_in) ** 2 + np.abs(q_cross) ** 2)
        #: significant (3σ, at most the hard bound) fluctuation and speed of each tip
        self.swing_m = np.minimum(3.0 * np.sqrt(power.sum(axis=1)), amp.sum(axis=1))
        self.speed_m_s = np.minimum(3.0 * np.sqrt((power * self.omega**2).sum(axis=1)), hard_v)
        #: how far each tip can go, for choosing the pulses to cast: mean + 6σ
        self.reach_m = np.minimum(
            np.abs(mean_in_m) + 6.0 * np.sqrt(power.sum(axis=1)), self.bound_m
        )

    @classmethod
    def turbulent(cls, structure: Structure, forcing: Forcing) -> SwayModel:
        """The sway under a turbulent wind (see the module's notes for the model)."""
        st, U = structure, float(forcing.speed_m_s)
        if U <= 0:
            raise InvalidParameterError(f"wind speed must be > 0, got {U}")
        freq, e_in, e_cr, w_in, l_in, l_cr, tip = _branch_dynamics(st, forcing)
        rng = np.random.default_rng(int(forcing.seed))
        lo, hi = FORCING_BAND_HZ
        edges = np.geomspace(lo, hi, N_COMPONENTS + 1)
        f_k = np.sqrt(edges[1:] * edges[:-1])
        s_u, s_v = _von_karman(f_k, U, forcing.turbulence_intensity * U)
        u_k = np.sqrt(2.0 * s_u * np.diff(edges)) * np.exp(1j * rng.uniform(0, 2 * np.pi, len(f_k)))
        v_k = np.sqrt(2.0 * s_v * np.diff(edges)) * np.exp(1j * rng.uniform(0, 2 * np.pi, len(f_k)))
        r = f_k[None, :] / freq[:, None]
        h = 1.0 / (1.0 - r * r + 2j * DAMPING_RATIO * r)
        g = (tip * U)[:, None] * h  # the static tip deflection per (m/s)², times U
        q_in = g * (2.0 * w_in[:, None] * u_k[None, :] + l_in[:, None] * v_k[None, :])
        q_cr = g * (l_cr[:, None] * v_k[None, :])
        mean = tip * U * U * w_in
        # linear bending holds for small deflections: a branch's own motion (mean + 3σ)
        # is scaled down to MAX_DEFLECTION of its length where the model would exceed it
        sigma = np.sqrt(0.5 * (np.abs(q_in) ** 2 + np.abs(q_cr) ** 2).sum(axis=1))
        reach = np.abs(mean) + 3.0 * sigma
        cap = MAX_DEFLECTION * st.length_b
        scale = np.where(reach > cap, cap / np.maximum(reach, 1e-300), 1.0)
        q_in, q_cr, mean = q_in * scale[:, None], q_cr * scale[:, None], mean * scale
        desc = {
            "forcing": "turbulent",
            "branches_capped": int((scale < 1.0).sum()),
            "wind_speed_m_s": U,
            "wind_direction_deg": float(forcing.direction_deg),
            "turbulence_intensity": float(forcing.turbulence_intensity),
            "seed": int(forcing.seed),
            "spectrum": f"von Kármán, integral length {TURBULENCE_LENGTH_M:g} m",
        }
        return cls(st, freq, e_in, e_cr, mean, f_k, q_in, q_cr, desc)

    @classmethod
    def sinusoid(
        cls,
        structure: Structure,
        amplitude_m: float,
        *,
        frequency_hz: float | None = None,
        direction_deg: float = 0.0,
        phase_rad: float = 0.0,
    ) -> SwayModel:
        """A steady sway of the stem (the branches with no parent) alone: its tip at
        ``amplitude_m × sin(2π f t + phase_rad)`` along ``direction_deg`` (horizontal,
        counter-clockwise from +x), ``f`` the model's stem frequency unless given.

        Examples
        --------
        >>> st = Structure(Cylinders(np.zeros((1, 3)), np.array([[0.0, 0, 1]]),
        ...     np.array([10.0]), np.array([0.1]), np.array([0.1]), np.array([-1]),
        ...     np.array([1]), np.array([0])))
        >>> m = SwayModel.sinusoid(st, 0.2, frequency_hz=0.5)
        >>> m.tips(0.5).round(6).tolist()
        [[0.2, 0.0, 0.0]]
        """
        st = structure
        freq, e_in, e_cr, *_ = _branch_dynamics(st, Forcing(1.0, direction_deg))
        if frequency_hz is not None:
            freq = np.where(st.parent_b < 0, float(frequency_hz), freq)
        f_stem = float(freq[st.parent_b < 0][0])
        w = _wind_vector(direction_deg)
        root = st.parent_b < 0
        e_in = np.where(root[:, None], w[None, :], e_in)
        q = np.zeros((st.nb, 1), dtype=complex)
        q[root, 0] = -1j * float(amplitude_m) * np.exp(1j * phase_rad)
        desc = {
            "forcing": "sinusoid",
            "amplitude_m": float(amplitude_m),
            "frequency_hz": f_stem,
            "direction_deg": float(direction_deg),
            "phase_rad": float(phase_rad),
        }
        zero = np.zeros(st.nb)
        return cls(st, freq, e_in, e_cr, zero, np.array([f_stem]), q, np.zeros_like(q), desc)

    def tips(self, t_s: float) -> np.ndarray:
        """(branches, 3): each branch's own tip displacement (m) at time ``t_s``."""
        return self.tips_many(np.array([float(t_s)]))[0]

    def tips_many(self, t_s: np.ndarray) -> np.ndarray:
        """(times, branches, 3): each branch's own tip displacement (m) at times ``t_s``
        (one matrix product for them all)."""
        e = np.exp(1j * np.outer(self.omega, np.asarray(t_s, dtype=np.float64)))
        q_in = self.mean_in_m[None, :] + (self.q_in @ e).real.T
        q_cr = (self.q_cross @ e).real.T
        return q_in[..., None] * self.e_in[None] + q_cr[..., None] * self.e_cross[None]

    def bases(self, tips: np.ndarray) -> np.ndarray:
        """(..., branches, 3): where each branch's base has moved, from the ``tips``
        (:meth:`tips`, or :meth:`tips_many`'s leading time axis)."""
        st = self.structure
        base = np.zeros_like(tips)
        for idx in st.levels()[1:]:
            p = st.parent_b[idx]
            base[..., idx, :] = (
                base[..., p, :] + mode_shape(st.xi_attach[idx])[:, None] * tips[..., p, :]
            )
        return base

    def displacement(
        self,
        t_s: float,
        branch: np.ndarray,
        xi: np.ndarray,
        tips: np.ndarray | None = None,
        phi: np.ndarray | None = None,
    ) -> np.ndarray:
        """(n, 3) displacement (m) at time ``t_s`` of axis points at ``xi`` (position
        over length) along branches ``branch`` (indices; -1: a still point, 0);
        ``tips``: the branches' :meth:`tips` at ``t_s`` and ``phi`` the points'
        :func:`mode_shape`, when already known."""
        tips = self.tips(t_s) if tips is None else tips
        base = self.bases(tips)
        b = np.maximum(branch, 0)
        out = base[b] + (mode_shape(xi) if phi is None else phi)[:, None] * tips[b]
        out[branch < 0] = 0.0
        return out

    def chain_sum(self, own: np.ndarray) -> np.ndarray:
        """Per branch: ``own`` summed over the branch and its ancestors (a bound of
        what its tip inherits, with ``φ <= 1``)."""
        st = self.structure
        total = own.astype(np.float64).copy()
        for idx in st.levels()[1:]:
            total[idx] += total[st.parent_b[idx]]
        return total

    def slice_error_m(self, half_s: float) -> float:
        """Largest pose error (m) of a slice posed at its mid time ``half_s`` away from
        its ends: each branch moves at most ``min(speed × half, 2 × swing)`` (3σ), its
        ancestors' share added."""
        own = np.minimum(self.speed_m_s * half_s, 2.0 * self.swing_m)
        return float(self.chain_sum(own).max()) if self.structure.nb else 0.0


def _wind_vector(direction_deg: float) -> np.ndarray:
    a = math.radians(direction_deg)
    return np.array([math.cos(a), math.sin(a), 0.0])


def _branch_dynamics(st: Structure, forcing: Forcing) -> tuple[np.ndarray, ...]:
    """Per branch: frequency (Hz), directions ``e_in`` and ``e_cross``, the wind's
    along- and lateral components on them, the first-mode drag (N per (m/s)²) along
    ``e_in`` and the modal stiffness (N/m)."""
    cyl = st.cyl
    w = _wind_vector(forcing.direction_deg)
    lat = np.array([-w[1], w[0], 0.0])
    a = st.axis_b
    w_perp = w[None, :] - (a @ w)[:, None] * a
    norm = np.linalg.norm(w_perp, axis=1, keepdims=True)
    fallback = np.cross(a, np.array([0.0, 0.0, 1.0]))
    fallback = np.where(np.linalg.norm(fallback, axis=1, keepdims=True) > 1e-9, fallback, [1, 0, 0])
    e_in = np.where(norm > 1e-9, w_perp / np.maximum(norm, 1e-300), fallback)
    e_in /= np.linalg.norm(e_in, axis=1, keepdims=True)
    e_cr = np.cross(a, e_in)
    e_cr /= np.maximum(np.linalg.norm(e_cr, axis=1, keepdims=True), 1e-300)
    sin_c = np.linalg.norm(np.cross(cyl.axis, w), axis=1)
    r_mean = 0.5 * (cyl.radius_m + cyl.end_radius_m)
    area = DRAG_WOOD * 2.0 * r_mean * cyl.length_m * sin_c + DRAG_LEAF * 0.5 * st.leaf_m2
    drag = 0.5 * AIR_DENSITY_KG_M3 * area
    mass = st.wood_kg + LEAF_MASS_KG_M2 * st.leaf_m2
    m_eff = np.maximum(st.modal_sums(mass, 2), 1e-12)
    own_wood = np.bincount(
        st.branch_of, weights=st.wood_kg * mode_shape(st.xi_mid) ** 2, minlength=st.nb
    )
    freq = _BEAM_COEFF * st.r_mean_b * math.sqrt(E_OVER_RHO) / np.maximum(st.length_b, 1e-6) ** 2
    freq = freq * np.sqrt(np.maximum(own_wood, 1e-12) / m_eff)
    roots = st.parent_b < 0
    dbh, height = st.stem_size()
    wood = st.subtree_sum(np.bincount(st.branch_of, weights=st.wood_kg, minlength=st.nb))
    leaf = st.subtree_sum(
        np.bincount(st.branch_of, weights=LEAF_MASS_KG_M2 * st.leaf_m2, minlength=st.nb)
    )
    f_stem = STEM_FREQUENCY_COEFF * dbh / height**2
    freq = np.where(roots, f_stem * np.sqrt(wood / np.maximum(wood + leaf, 1e-12)), freq)
    tip = _static_tip_m(st, drag, r_mean)
    return freq, e_in, e_cr, e_in @ w, e_in @ lat, e_cr @ lat, tip


#: A wood vertex belongs to a cylinder when it lies within this share of the radius
#: (plus :data:`WOOD_TOLERANCE_M`) of its surface; a leaf vertex follows the nearest
#: cylinder within :data:`LEAF_REACH_M` of its axis.
WOOD_TOLERANCE = 0.3
WOOD_TOLERANCE_M = 0.005
LEAF_REACH_M = 1.0
_NEIGHBOURS = 12


def assign_vertices(
    cyl: Cylinders, vertices: np.ndarray, leaf: np.ndarray, movable: np.ndarray
) -> np.ndarray:
    """The cylinder each vertex follows (-1: none, it stays still).

    A vertex of a wood (or other) triangle follows the cylinder whose surface it lies
    on (within ``WOOD_TOLERANCE × r + WOOD_TOLERANCE_M``: meshes of the table, prisms or
    mitred tubes, lie on it); a leaf vertex the cylinder whose axis is nearest, within
    :data:`LEAF_REACH_M` (the stem it grows on). Candidates are the cylinders of the
    :data:`_NEIGHBOURS` nearest points sampled along the axes; each is then measured
    exactly (distance to the axis segment).

    Parameters
    ----------
    cyl : Cylinders
        In the vertices' frame.
    vertices : (v, 3) float64
    leaf, movable : (v,) bool
        Vertices of leaf triangles; vertices that may move at all (not ground).

    Returns
    -------
    (v,) int64

    Examples
    --------
    >>> cyl = Cylinders(np.zeros((1, 3)), np.array([[0.0, 0, 1]]), np.array([2.0]),
    ...     np.array([0.1]), np.array([0.1]), np.array([-1]), np.array([0]), np.array([0]))
    >>> v = np.array([[0.1, 0, 1], [0.5, 0, 1], [3.0, 0, 0]])
    >>> assign_vertices(cyl, v, np.array([False, True, True]), np.ones(3, bool)).tolist()
    [0, 0, -1]
    """
    from scipy.spatial import cKDTree

    out = np.full(len(vertices), -1, dtype=np.int64)
    idx = np.flatnonzero(movable)
    if not len(idx) or cyl.n == 0:
        return out
    step = np.clip(0.5 * np.minimum(cyl.radius_m, cyl.length_m), 0.01, 0.25)
    n_s = np.maximum(2, np.ceil(cyl.length_m / step).astype(np.int64) + 1)
    owner = np.repeat(np.arange(cyl.n), n_s)
    frac = np.concatenate([np.linspace(0.0, 1.0, k) for k in n_s])
    samples = cyl.start[owner] + (frac * cyl.length_m[owner])[:, None] * cyl.axis[owner]
    k = min(_NEIGHBOURS, len(samples))
    _, nn = cKDTree(samples).query(vertices[idx], k=k)
    cand = owner[nn.reshape(len(idx), k)]
    p = vertices[idx][:, None, :]
    rel = p - cyl.start[cand]
    along = np.clip(np.einsum("ijk,ijk->ij", rel, cyl.axis[cand]), 0.0, cyl.length_m[cand])
    foot = cyl.start[cand] + along[..., None] * cyl.axis[cand]
    dist = np.linalg.norm(p - foot, axis=2)
    t = along / np.maximum(cyl.length_m[cand], 1e-300)
    r = cyl.radius_m[cand] + t * (cyl.end_radius_m[cand] - cyl.radius_m[cand])
    is_leaf = leaf[idx][:, None]
    score = np.where(is_leaf, dist, np.abs(dist - r))
    best = np.argmin(score, axis=1)
    rows = np.arange(len(idx))
    s_best, r_best = score[rows, best], r[rows, best]
    ok = np.where(
        leaf[idx], s_best <= LEAF_REACH_M, s_best <= WOOD_TOLERANCE * r_best + WOOD_TOLERANCE_M
    )
    out[idx[ok]] = cand[rows, best][ok]
    return out


class MovingScene:
    """A scene whose tree parts sway: its triangles posed at any time.

    Parameters
    ----------
    vertices : (v, 3) float64
        The scene's vertices in the scan's local frame.
    faces : (f, 3) int64
    face_label : (f,) uint8
    face_tree : (f,) uint32 or None
    cyl : Cylinders
        The tree's table in the same local frame.
    model_for : callable(Structure) -> SwayModel
        Builds the sway once the leaves are assigned (their area loads the branches).
    """

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        face_label: np.ndarray,
        face_tree: np.ndarray | None,
        cyl: Cylinders,
        model_for: Any,
    ) -> None:
        self.v, self.faces, self.face_label, self.face_tree = vertices, faces, face_label, face_tree
        leaf_code, ground_code = LABEL_CODES["leaf"], LABEL_CODES["ground"]
        leaf = np.zeros(len(vertices), bool)
        leaf[faces[face_label == leaf_code].ravel()] = True
        movable = np.zeros(len(vertices), bool)
        movable[faces[face_label != ground_code].ravel()] = True
        used = np.zeros(len(vertices), bool)
        used[faces.ravel()] = True
        self.cyl_of = assign_vertices(cyl, vertices, leaf, movable & used)
        leaf_faces = faces[face_label == leaf_code]
        area = leaf_area_per_cylinder(self.cyl_of, vertices, leaf_faces, cyl.n)
        self.structure = Structure(cyl, area)
        self.model: SwayModel = model_for(self.structure)
        st = self.structure
        c = np.maximum(self.cyl_of, 0)
        self.branch = np.where(self.cyl_of >= 0, st.branch_of[c], -1)
        rel = vertices - cyl.start[c]
        along = np.clip(np.einsum("ij,ij->i", rel, cyl.axis[c]), 0.0, cyl.length_m[c])
        self.xi = (st.s0[c] + along) / st.length_b[st.branch_of[c]]
        self.phi = mode_shape(self.xi)
        #: how far (m) each vertex can go (mean + 6σ of each branch, :attr:`SwayModel.
        #: reach_m`, its ancestors' added): the pulses a station casts cover it
        self.reach_v = self.vertex_bound(self.model.reach_m)
        self.n_moving = int((self.cyl_of >= 0).sum())
        self.n_movable = int((movable & used).sum())

    def vertex_bound(self, per_branch: np.ndarray) -> np.ndarray:
        """(v,) per vertex: ``per_branch`` summed over its branch and ancestors (0 for
        still vertices): a bound of its displacement when ``per_branch`` bounds each
        branch's own tip (``φ <= 1``)."""
        chain = self.model.chain_sum(per_branch)
        return np.where(self.cyl_of >= 0, chain[np.maximum(self.branch, 0)], 0.0)

    def posed(
        self, t_s: float, tri: np.ndarray, tips: np.ndarray | None = None
    ) -> tuple[np.ndarray, ...]:
        """Triangles ``tri`` (indices) posed at ``t_s`` (``tips``: the model's
        :meth:`~SwayModel.tips` then, if known): their vertices (compacted, float64,
        local frame), faces into them, the vertices' displacements (m)."""
        f = self.faces[tri]
        mark = np.zeros(len(self.v), dtype=bool)
        mark[f.ravel()] = True
        used = np.flatnonzero(mark)
        index = np.cumsum(mark) - 1
        disp = self.model.displacement(t_s, self.branch[used], self.xi[used], tips, self.phi[used])
        return self.v[used] + disp, index[f], disp


def hit_displacement_m(
    posed_v: np.ndarray, faces: np.ndarray, disp: np.ndarray, prim: np.ndarray, p: np.ndarray
) -> np.ndarray:
    """How far (m) each hit ``p`` on triangle ``prim`` of a posed mesh has moved from
    rest: the vertices' displacements weighted by ``p``'s barycentric coordinates."""
    f = faces[prim]
    a, b, c = posed_v[f[:, 0]], posed_v[f[:, 1]], posed_v[f[:, 2]]
    v0, v1, v2 = b - a, c - a, p - a
    d00 = np.einsum("ij,ij->i", v0, v0)
    d01 = np.einsum("ij,ij->i", v0, v1)
    d11 = np.einsum("ij,ij->i", v1, v1)
    d20 = np.einsum("ij,ij->i", v2, v0)
    d21 = np.einsum("ij,ij->i", v2, v1)
    den = np.maximum(d00 * d11 - d01 * d01, 1e-300)
    wb = (d11 * d20 - d01 * d21) / den
    wc = (d00 * d21 - d01 * d20) / den
    wa = 1.0 - wb - wc
    u = wa[:, None] * disp[f[:, 0]] + wb[:, None] * disp[f[:, 1]] + wc[:, None] * disp[f[:, 2]]
    return np.linalg.norm(u, axis=1)


__all__ = [
    "WIND_FIELD",
    "Cylinders",
    "Forcing",
    "MovingScene",
    "Structure",
    "SwayModel",
    "assign_vertices",
    "cylinders_from",
    "hit_displacement_m",
    "leaf_area_per_cylinder",
    "mode_shape",
]


def _static_tip_m(st: Structure, drag: np.ndarray, r_mean: np.ndarray) -> np.ndarray:
    """Per branch: its tip's static deflection (m per (m/s)² of wind) under the drag of
    its own cylinders (``drag``, N per (m/s)², at their middles) and of its children's
    subtrees (at their attachments): the bending moment ``M(s)`` over ``E I(s)``
    integrated against the lever to the tip (cylinder by cylinder, midpoint rule)."""
    cyl = st.cyl
    sub = st.subtree_sum(np.bincount(st.branch_of, weights=drag, minlength=st.nb))
    s_mid = st.s0 + 0.5 * cyl.length_m
    ei = YOUNG_MODULUS_PA * math.pi * np.maximum(r_mean, 1e-5) ** 4 / 4.0
    child = np.flatnonzero(st.parent_b >= 0)
    pos = np.concatenate([s_mid, st.xi_attach[child] * st.length_b[st.parent_b[child]]])
    force = np.concatenate([drag, sub[child]])
    owner = np.concatenate([st.branch_of, st.parent_b[child]])
    rows = np.argsort(st.branch_of, kind="stable")
    cut = np.searchsorted(st.branch_of[rows], np.arange(st.nb + 1))
    loads = np.argsort(owner, kind="stable")
    lcut = np.searchsorted(owner[loads], np.arange(st.nb + 1))
    tip = np.zeros(st.nb)
    for b in range(st.nb):
        c = rows[cut[b] : cut[b + 1]]
        i = loads[lcut[b] : lcut[b + 1]]
        lever = pos[i][None, :] - s_mid[c][:, None]
        moment = (force[i][None, :] * np.maximum(lever, 0.0)).sum(axis=1)
        tip[b] = (moment / ei[c] * cyl.length_m[c] * (st.length_b[b] - s_mid[c])).sum()
    return tip


#: Default largest motion of the tree within one time slice, as a share of the point
#: spacing at the tree's nearest range (3σ speeds).
SLICE_FRACTION = 0.25


@dataclass(frozen=True)
class Wind:
    """What moves a scan's tree and how: the argument ``wind`` of :func:`treesim.scan.scan`.

    Parameters
    ----------
    cylinders : CylinderTable, Cylinders, str or Path, optional
        The tree's cylinder table (a :class:`treesim.models.CylinderTable`, or a
        treesim CSV file), in the scene's coordinates. None: nothing can move.
    forcing : Forcing, optional
        A turbulent wind (:meth:`SwayModel.turbulent`).
    sinusoid_amplitude_m : float, optional
        Instead of ``forcing``: the stem sways steadily (:meth:`SwayModel.sinusoid`),
        its tip ``sinusoid_amplitude_m`` along ``direction_deg`` at
        ``sinusoid_frequency_hz`` (default: the stem's frequency).
    slice_fraction : float
        Largest motion within a time slice, as a share of the point spacing.

    Examples
    --------
    >>> Wind("tree.cylinders.csv", Forcing(5.0)).slice_fraction
    0.25
    """

    cylinders: Any = None
    forcing: Forcing | None = None
    sinusoid_amplitude_m: float | None = None
    sinusoid_frequency_hz: float | None = None
    direction_deg: float = 0.0
    slice_fraction: float = SLICE_FRACTION

    def __post_init__(self) -> None:
        if self.forcing is None and self.sinusoid_amplitude_m is None:
            raise InvalidParameterError("wind needs a forcing or a sinusoid's amplitude")
        if not 0 < self.slice_fraction <= 10:
            raise InvalidParameterError(
                f"slice_fraction must be in (0, 10], got {self.slice_fraction}"
            )

    @classmethod
    def from_spec(cls, spec: Any) -> Wind | None:
        """The wind of a :class:`~treesim.params.ScannerSpec` (None at 0 m/s)."""
        if spec.wind_speed_m_s <= 0:
            return None
        forcing = Forcing(
            spec.wind_speed_m_s,
            spec.wind_direction_deg,
            spec.wind_turbulence_intensity,
            spec.wind_seed,
        )
        return cls(spec.wind_cylinders, forcing, direction_deg=spec.wind_direction_deg)

    def cylinder_table(self) -> Cylinders | None:
        """The table as :class:`Cylinders` (read from its file), or None."""
        if self.cylinders is None:
            return None
        if isinstance(self.cylinders, str | Path):
            # the model library's reader: any table format it reads (treesim's own,
            # TreeQSM, SimpleForest), validated, with its messages naming the bad row
            from ..models import read_cylinders

            return cylinders_from(read_cylinders(self.cylinders))
        return cylinders_from(self.cylinders)

    def model_for(self, structure: Structure) -> SwayModel:
        """The sway of ``structure`` under this wind."""
        if self.sinusoid_amplitude_m is not None:
            return SwayModel.sinusoid(
                structure,
                self.sinusoid_amplitude_m,
                frequency_hz=self.sinusoid_frequency_hz,
                direction_deg=self.direction_deg,
            )
        assert self.forcing is not None
        return SwayModel.turbulent(structure, self.forcing)


__all__ += ["SLICE_FRACTION", "Wind"]


class Sectors:
    """Which triangles a run of scan columns of one station can meet, in any pose near a
    reference pose.

    Each triangle's azimuth interval seen from the station (scanner frame, relative to
    the direction of the scene's centre) in the reference pose, widened by the angle its
    vertices' distance from that pose subtends at its nearest horizontal distance;
    triangles whose interval spans more than a half turn, or that the motion can carry
    over the station's vertical axis, are always taken.

    Parameters
    ----------
    vertices : (v, 3) float64
        The reference pose (local frame).
    faces : (f, 3) int64
    o : (3,) float64
        The station (local frame).
    rot : (3, 3) float64
        The station's rotation (scanner to scene frame).
    bound_v : (v,) float64
        How far each vertex lies at most from the reference pose in the poses cast (m).
    """

    def __init__(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        o: np.ndarray,
        rot: np.ndarray,
        bound_v: np.ndarray,
    ) -> None:
        rel = (vertices - o) @ rot
        lo, hi = rel.min(axis=0), rel.max(axis=0)
        c = 0.5 * (lo + hi)
        self.ref = math.atan2(c[1], c[0])
        az = _wrap(np.arctan2(rel[:, 1], rel[:, 0]) - self.ref)
        dist = np.hypot(rel[:, 0], rel[:, 1])
        f = faces
        taz = az[f]
        self.lo, self.hi = taz.min(axis=1), taz.max(axis=1)
        r0, r1, r2 = rel[f[:, 0]], rel[f[:, 1]], rel[f[:, 2]]
        edge = np.sqrt(np.maximum(np.maximum(_sq(r1 - r0), _sq(r2 - r1)), _sq(r0 - r2)))
        near = dist[f].min(axis=1) - edge
        reach = bound_v[f].max(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            margin = np.arcsin(np.clip(reach / near, 0.0, 1.0))
        self.always = (self.hi - self.lo > math.pi) | (near <= reach) | ~np.isfinite(margin)
        self.lo = self.lo - np.where(self.always, 0.0, margin)
        self.hi = self.hi + np.where(self.always, 0.0, margin)
        self.all = np.arange(len(f))

    def triangles(self, az_cols: list[np.ndarray], pad_rad: float) -> np.ndarray:
        """Indices of the triangles that columns of azimuths ``az_cols`` (rad, scanner
        frame; one array per run of neighbouring columns) can meet, ``pad_rad`` wider."""
        keep = self.always.copy()
        for az in az_cols:
            if not len(az):
                continue
            a = _wrap(np.asarray(az) - self.ref)
            if a.max() - a.min() > math.pi:
                return self.all
            keep |= (self.hi >= a.min() - pad_rad) & (self.lo <= a.max() + pad_rad)
        return np.flatnonzero(keep)


def _sq(e: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", e, e)


def _wrap(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-π, π)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def slice_duration_s(model: SwayModel, limit_m: float, max_s: float) -> float:
    """The longest time slice (s, at most ``max_s``) that, posed at its mid time, keeps
    every part within ``limit_m`` of where it is (:meth:`SwayModel.slice_error_m`).

    Examples
    --------
    >>> st = Structure(Cylinders(np.zeros((1, 3)), np.array([[0.0, 0, 1]]),
    ...     np.array([10.0]), np.array([0.1]), np.array([0.1]), np.array([-1]),
    ...     np.array([1]), np.array([0])))
    >>> m = SwayModel.sinusoid(st, 0.1, frequency_hz=1.0)
    >>> round(slice_duration_s(m, 0.005, 100.0), 5)  # 2 × 0.005 m / 0.628 m/s
    0.01592
    """
    if model.slice_error_m(0.5 * max_s) <= limit_m:
        return float(max_s)
    lo, hi = 0.0, float(max_s)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if model.slice_error_m(0.5 * mid) <= limit_m:
            lo = mid
        else:
            hi = mid
    return max(lo, 1e-12)


def moving_warnings(moving: MovingScene) -> list[str]:
    """Warnings of a windy scan: vertices of tree parts that follow no cylinder."""
    still = moving.n_movable - moving.n_moving
    if still <= 0.01 * max(moving.n_movable, 1):
        return []
    return [
        f"wind: {still:,} of {moving.n_movable:,} vertices of the scene's wood, leaf and "
        "other parts lie on no cylinder of the table (another object, or a table that "
        "does not match the mesh): they stayed still"
    ]


def wind_summary(moving: MovingScene, wind: Wind, stations: list[dict[str, Any]]) -> dict[str, Any]:
    """JSON-ready account of a windy scan: the model, the tree's figures, the slices."""
    m, st = moving.model, moving.structure
    roots = st.parent_b < 0
    dbh, height = st.stem_size()
    return {
        **m.description,
        "model": "first-mode cantilevers on their parents (treesim.scan.wind)",
        "dbh_m": dbh,
        "height_m": height,
        "stem_frequency_hz": float(m.frequency_hz[roots][0]),
        "branch_frequency_hz": {
            "min": float(m.frequency_hz.min()),
            "median": float(np.median(m.frequency_hz)),
            "max": float(m.frequency_hz.max()),
        },
        "branches": int(st.nb),
        "stem_tip_mean_m": float(m.mean_in_m[roots][0]),
        "stem_tip_swing_3sigma_m": float(m.swing_m[roots][0]),
        "largest_reach_m": float(moving.reach_v.max()) if len(moving.reach_v) else 0.0,
        "vertices_moving": moving.n_moving,
        "vertices_still": int(len(moving.v) - moving.n_moving),
        "slice_fraction": wind.slice_fraction,
        "stations": stations,
    }


__all__ += ["Sectors", "moving_warnings", "slice_duration_s", "wind_summary"]
