"""Synthetic stands: plausible plots of procedural trees, seeded and reproducible.

The rules (sources in the README's Plots section; research notes B2):

* **Count**: exactly ``round(stems_per_ha × π r² / 10 000)`` trees (``count="exact"``,
  default), or a Poisson draw with that mean (``count="poisson"``).
* **Species**: by the given shares, as exact counts (largest remainders), in random order.
* **DBH**: a three-parameter Weibull (shape ``weibull_shape``, default 3: even-aged;
  location ``dbh_min_m`` 5 cm, or half the mean for species smaller than twice that)
  whose scale gives the species' mean DBH exactly: the
  preset tree's own DBH (seed 0) unless ``mean_dbh_m`` is given. Draws beyond 2.5 × the
  mean are drawn again.
* **Height**: Näslund, h = 1.3 + d² / (a + b·d)² (d in cm, h in m), b = ``naslund_b``
  (0.22) and, per species, the a that puts the preset tree's own DBH and height on the
  curve; times lognormal noise exp(σ·N(0, 1)), σ = ``height_sd`` (0.1).
* **Positions**: sequential inhibition (Matérn type III-like), biggest trees first: a
  uniform point in the plot's disc is kept if it is at least
  ``max(spacing_fraction × s, dbh_spacing_factor × (d_i + d_j))`` from every tree
  already placed, s = sqrt(10 000 / stems_per_ha) the mean spacing; after 2 000 refused
  tries the distance is relaxed by 10 % (and the relaxation reported).
* **Trees**: rotation uniform in [0, 360)°, each its own seed; the species' trunk length
  and radius ratio are fitted to the drawn DBH and height
  (:func:`treesim.plot._sources.fit_species`); the exact figures are
  :meth:`Plot.truth`'s.

Everything comes from one ``numpy.random.default_rng(seed)``: the same arguments give
the same plot, bit for bit.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InvalidParameterError
from ..params._fields import check_bounds, param
from .core import Plot, PlotTree, Terrain

__all__ = ["COUNT_RULES", "MAX_TREES", "StandParams", "generate_stand", "parse_shares", "write_map"]

#: The plot radius ``treesim plot generate`` uses when none is given (m).
DEFAULT_RADIUS_M = 15.0
#: How the number of trees is chosen.
COUNT_RULES = ("exact", "poisson")
#: Tries before the inhibition distance is relaxed by 10 %.
TRIES = 2000
#: Most trees in one generated stand.
MAX_TREES = 5000


@dataclass(frozen=True, kw_only=True)
class StandParams:
    """A synthetic stand (``treesim plot generate``, the service's ``stand`` parameter):
    the arguments of :func:`generate_stand`, with their ranges.

    Examples
    --------
    >>> import treesim as ts
    >>> ts.StandParams(species="aspen:0.6,balsam-fir:0.4", stems_per_ha=800.0).count
    'exact'
    """

    species: str = param(
        "aspen",
        help="species and their shares, NAME:SHARE,... (e.g. aspen:0.6,balsam-fir:0.4)",
    )
    stems_per_ha: float = param(600.0, help="stand density (stems per hectare)", gt=0, le=20_000)
    radius_m: float = param(DEFAULT_RADIUS_M, help="plot radius", unit="m", gt=0, le=100)
    seed: int = param(0, help="seed of the stand and its trees", ge=0, le=2**31 - 1)
    count: str = param(
        "exact",
        help="number of trees: exact (rounded stems/ha x area) or Poisson",
        choices=COUNT_RULES,
    )
    mean_dbh_m: float | None = param(
        None,
        help="mean DBH of every species",
        unit="m",
        none_means="each preset tree's own",
        gt=0,
        le=3,
    )
    weibull_shape: float = param(
        3.0, help="Weibull shape of the DBHs (2-4: even-aged)", gt=0, le=50
    )
    slope_deg: float = param(0.0, help="terrain slope (0: flat)", unit="deg", ge=0, lt=60)
    aspect_deg: float = param(
        0.0,
        help="direction the slope faces, compass degrees (0 north, 90 east)",
        unit="deg",
        ge=0,
        lt=360,
    )
    leaves: bool | None = param(None, help="procedural leaves", none_means="the species' own")
    facets: int = param(16, help="vertices per ring of the trees' tubes", ge=3, le=256)

    def __post_init__(self) -> None:
        check_bounds(self)
        parse_shares(self.species)  # names a species that does not exist

    @property
    def expected_trees(self) -> float:
        """stems/ha × the plot's area."""
        return self.stems_per_ha * math.pi * self.radius_m**2 / 1e4

    def generate(self, terrain: Terrain | None = None) -> tuple[Plot, dict[str, Any]]:
        """(plot, stand): :func:`generate_stand` with these settings, on ``terrain``
        (default: flat, or the plane of ``slope_deg`` and ``aspect_deg``)."""
        if terrain is None:
            kind = "slope" if self.slope_deg else "flat"
            terrain = Terrain(kind=kind, slope_deg=self.slope_deg, aspect_deg=self.aspect_deg)
        return generate_stand(
            self.species,
            self.stems_per_ha,
            self.radius_m,
            self.seed,
            terrain=terrain,
            facets=self.facets,
            count=self.count,
            mean_dbh_m=self.mean_dbh_m,
            weibull_shape=self.weibull_shape,
            leaves=self.leaves,
        )


def parse_shares(text: str | Mapping[str, float]) -> dict[str, float]:
    """``"aspen:0.6,balsam-fir:0.4"`` (or a mapping) as shares summing to 1."""
    from ..models import SPECIES

    if isinstance(text, Mapping):
        items = [(str(k), v) for k, v in text.items()]
    else:
        items = []
        for chunk in str(text).split(","):
            chunk = chunk.strip()
            if not chunk:
                continue
            name, sep, share = chunk.partition(":")
            items.append((name.strip(), share.strip() if sep else "1"))
    if not items:
        raise InvalidParameterError("give at least one species, e.g. aspen:0.6,balsam-fir:0.4")
    out: dict[str, float] = {}
    for name, share in items:
        if name not in SPECIES:
            raise InvalidParameterError(
                f"unknown species {name!r}; choose from {', '.join(SPECIES)}"
            )
        try:
            v = float(share)
        except (TypeError, ValueError):
            raise InvalidParameterError(f"{name}: share must be a number, got {share!r}") from None
        if not (math.isfinite(v) and v > 0):
            raise InvalidParameterError(f"{name}: share must be > 0, got {share!r}")
        out[name] = out.get(name, 0.0) + v
    total = sum(out.values())
    return {k: v / total for k, v in out.items()}


@lru_cache(maxsize=32)
def _preset_size(species: str) -> tuple[float, float]:
    """The preset tree's own DBH and height (seed 0)."""
    from ..models import generate_tree

    s = generate_tree(species, seed=0, leaves=False).cylinders.summary()
    return float(s["dbh_m"]), float(s["height_m"])


def _naslund_a(d_m: float, h_m: float, b: float) -> float:
    d = 100.0 * d_m
    return d / math.sqrt(h_m - 1.3) - b * d


def naslund_height_m(d_m: np.ndarray | float, a: float, b: float) -> np.ndarray:
    """Näslund's height (m) of DBH ``d_m`` (m): 1.3 + d² / (a + b·d)², d in cm."""
    d = 100.0 * np.asarray(d_m, dtype=np.float64)
    return 1.3 + d * d / (a + b * d) ** 2


def _counts(shares: dict[str, float], n: int) -> dict[str, int]:
    raw = {k: v * n for k, v in shares.items()}
    out = {k: int(math.floor(v)) for k, v in raw.items()}
    left = n - sum(out.values())
    for k in sorted(raw, key=lambda k: (-(raw[k] - out[k]), k))[:left]:
        out[k] += 1
    return out


def _check_stand(
    stems_per_ha: float,
    radius_m: float,
    seed: int,
    count: str,
    mean_dbh_m: float | None,
    weibull_shape: float,
    dbh_min_m: float,
    naslund_b: float,
    height_sd: float,
    spacing_fraction: float,
    dbh_spacing_factor: float,
) -> None:
    """Refuse arguments out of range (an :class:`InvalidParameterError` naming each)."""
    for name, v, lo in (
        ("stems_per_ha", stems_per_ha, 0.0),
        ("radius_m", radius_m, 0.0),
        ("weibull_shape", weibull_shape, 0.0),
        ("naslund_b", naslund_b, 0.0),
        ("spacing_fraction", spacing_fraction, -1e-300),
        ("dbh_spacing_factor", dbh_spacing_factor, -1e-300),
        ("height_sd", height_sd, -1e-300),
        ("dbh_min_m", dbh_min_m, -1e-300),
    ):
        if isinstance(v, bool) or not (isinstance(v, int | float) and math.isfinite(v) and v > lo):
            raise InvalidParameterError(f"{name} must be {'>= 0' if lo < 0 else '> 0'}, got {v!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InvalidParameterError(f"seed must be an integer >= 0, got {seed!r}")
    if count not in COUNT_RULES:
        raise InvalidParameterError(f"count must be one of {', '.join(COUNT_RULES)}, got {count!r}")
    if mean_dbh_m is not None and not (math.isfinite(mean_dbh_m) and mean_dbh_m > 0):
        raise InvalidParameterError(f"mean_dbh_m must be > 0, got {mean_dbh_m!r}")


def _species_rules(
    shares: dict[str, float],
    counts: dict[str, int],
    mean_dbh_m: float | None,
    weibull_shape: float,
    dbh_min_m: float,
    naslund_b: float,
) -> dict[str, dict[str, Any]]:
    """Each species' DBH distribution (Weibull location and scale) and height curve
    (Näslund's a and b), from its preset tree's own size."""
    g = math.gamma(1.0 + 1.0 / weibull_shape)
    rules: dict[str, Any] = {}
    for name in shares:
        d0, h0 = _preset_size(name)
        mean = float(mean_dbh_m) if mean_dbh_m is not None else d0
        # a species smaller than the location (a sapling) starts at half its mean
        loc = min(float(dbh_min_m), 0.5 * mean)
        scale = (mean - loc) / g
        a = _naslund_a(d0, h0, naslund_b)
        rules[name] = {
            "share": shares[name],
            "trees": counts[name],
            "mean_dbh_m": mean,
            "weibull_location_m": loc,
            "weibull_scale_m": scale,
            "naslund_a": a,
            "naslund_b": naslund_b,
            "preset_dbh_m": d0,
            "preset_height_m": h0,
        }
    return rules


def _draw_sizes(
    names: list[str],
    rules: dict[str, dict[str, Any]],
    rng: np.random.Generator,
    weibull_shape: float,
    height_sd: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Each tree's DBH (Weibull, drawn again beyond 2.5 × the mean) and height (its
    species' curve times lognormal noise)."""
    n = len(names)
    dbh = np.empty(n)
    height = np.empty(n)
    for i, name in enumerate(names):
        r = rules[name]
        while True:
            d = r["weibull_location_m"] + r["weibull_scale_m"] * rng.weibull(weibull_shape)
            if d <= 2.5 * r["mean_dbh_m"]:
                break
        dbh[i] = d
        h = float(naslund_height_m(d, r["naslund_a"], r["naslund_b"]))
        height[i] = 1.3 + (h - 1.3) * math.exp(height_sd * rng.standard_normal())
    return dbh, height


def _place(
    dbh: np.ndarray,
    radius_m: float,
    spacing: float,
    spacing_fraction: float,
    dbh_spacing_factor: float,
    rng: np.random.Generator,
) -> tuple[np.ndarray, int]:
    """Positions by sequential inhibition, biggest first (the module's rule), and how
    often the distance was relaxed."""
    n = len(dbh)
    xy = np.empty((n, 2))
    relaxed = 0
    placed = 0
    order_done = np.empty(n, dtype=np.int64)
    for i in np.argsort(-dbh, kind="stable"):
        factor = 1.0
        tries = 0
        while True:
            rr = radius_m * math.sqrt(rng.random())
            th = 2.0 * math.pi * rng.random()
            p = np.array([rr * math.cos(th), rr * math.sin(th)])
            if placed == 0:
                break
            done = order_done[:placed]
            need = factor * np.maximum(
                spacing_fraction * spacing, dbh_spacing_factor * (dbh[i] + dbh[done])
            )
            if np.all(np.hypot(*(xy[done] - p).T) >= need):
                break
            tries += 1
            if tries >= TRIES:
                factor *= 0.9
                tries = 0
                relaxed += 1
        xy[i] = p
        order_done[placed] = i
        placed += 1
    return xy, relaxed


def generate_stand(
    species: str | Mapping[str, float],
    stems_per_ha: float,
    radius_m: float,
    seed: int = 0,
    *,
    terrain: Terrain | None = None,
    facets: int = 16,
    count: str = "exact",
    mean_dbh_m: float | None = None,
    weibull_shape: float = 3.0,
    dbh_min_m: float = 0.05,
    naslund_b: float = 0.22,
    height_sd: float = 0.1,
    spacing_fraction: float = 0.5,
    dbh_spacing_factor: float = 5.0,
    leaves: bool | None = None,
) -> tuple[Plot, dict[str, Any]]:
    """A synthetic stand (the rules are the module's).

    Parameters
    ----------
    species : str or mapping of str to float
        One species, or shares of several (``"aspen:0.6,balsam-fir:0.4"`` or a mapping); the
        names are :data:`treesim.models.SPECIES`.
    stems_per_ha : float
        The stand's density.
    radius_m : float
        The plot's radius.
    seed : int, optional
        Seeds the one random generator that draws everything.
    terrain : Terrain, optional
        The ground (flat at 0 m by default).
    facets : int, optional
        Facets round each tube of the trees' meshes.
    count : {"exact", "poisson"}, optional
        ``exact``: the expected number of trees, rounded; ``poisson``: a Poisson draw.
    mean_dbh_m : float, optional
        The mean DBH of every species (default: each preset tree's own DBH).
    weibull_shape : float, optional
        The DBH distribution's shape.
    dbh_min_m : float, optional
        The DBH distribution's location.
    naslund_b : float, optional
        The height curve's ``b``.
    height_sd : float, optional
        The lognormal noise on heights.
    spacing_fraction : float, optional
        The minimum distance between stems as a fraction of the mean spacing.
    dbh_spacing_factor : float, optional
        The minimum distance between stems as a multiple of their DBHs' sum.
    leaves : bool, optional
        Leaves on or off (default: each species' own).

    Returns
    -------
    plot : Plot
        Its trees (``source="species"``, with ``dbh_m``/``height_m`` targets), centred
        on (0, 0).
    stand : dict
        The rules and figures used (JSON/TOML-ready): what ``plot.toml``'s ``[stand]``
        holds.

    Examples
    --------
    >>> import treesim as ts
    >>> plot, stand = ts.generate_stand("aspen:0.6,balsam-fir:0.4", 600.0, 8.0, seed=1)
    >>> len(plot.tree_ids) == stand["trees"] == round(600.0 * 3.141592653589793 * 8.0**2 / 1e4)
    True
    """
    shares = parse_shares(species)
    _check_stand(
        stems_per_ha,
        radius_m,
        seed,
        count,
        mean_dbh_m,
        weibull_shape,
        dbh_min_m,
        naslund_b,
        height_sd,
        spacing_fraction,
        dbh_spacing_factor,
    )
    area_ha = math.pi * radius_m**2 / 1e4
    expected = stems_per_ha * area_ha
    rng = np.random.default_rng(seed)
    n = int(round(expected)) if count == "exact" else int(rng.poisson(expected))
    if n > MAX_TREES:
        raise InvalidParameterError(
            f"{n} trees: more than {MAX_TREES} in one plot; lower --stems-per-ha or --radius-m"
        )
    counts = _counts(shares, n)
    names = [k for k in shares for _ in range(counts[k])]
    names = [names[i] for i in rng.permutation(n)]
    # DBH and height per species' curve
    rules = _species_rules(shares, counts, mean_dbh_m, weibull_shape, dbh_min_m, naslund_b)
    dbh, height = _draw_sizes(names, rules, rng, weibull_shape, height_sd)
    # positions: sequential inhibition, biggest first
    spacing = math.sqrt(1e4 / stems_per_ha)
    xy, relaxed = _place(dbh, radius_m, spacing, spacing_fraction, dbh_spacing_factor, rng)
    rot = rng.uniform(0.0, 360.0, n)
    seeds = rng.integers(0, 2**31 - 1, n)
    trees = [
        PlotTree(
            tree_id=i + 1,
            x_m=float(xy[i, 0]),
            y_m=float(xy[i, 1]),
            rotation_deg=float(rot[i]),
            source="species",
            species=names[i],
            seed=int(seeds[i]),
            leaves=leaves,
            dbh_m=float(dbh[i]),
            height_m=float(height[i]),
        )
        for i in range(n)
    ]
    plot = Plot(trees, terrain=terrain or Terrain(), radius_m=float(radius_m), facets=int(facets))
    stand = {
        "seed": seed,
        "stems_per_ha": float(stems_per_ha),
        "radius_m": float(radius_m),
        "count_rule": count,
        "trees": n,
        "expected_trees": expected,
        "weibull_shape": float(weibull_shape),
        "dbh_min_m": float(dbh_min_m),
        "height_sd": float(height_sd),
        "mean_spacing_m": spacing,
        "min_distance_rule": (
            f"max({spacing_fraction:g} x mean spacing, {dbh_spacing_factor:g} x (DBH_i + DBH_j))"
        ),
        "spacing_fraction": float(spacing_fraction),
        "dbh_spacing_factor": float(dbh_spacing_factor),
        "relaxations": relaxed,
        "species": rules,
    }
    return plot, stand


def write_map(path: str | Path, plot: Plot, *, title: str = "") -> Path:
    """A small PNG map of the plot: stems drawn at 5 × their target DBH (0.2 m where a
    tree has none), coloured by species, the plot's circle."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Circle

    from ..atomic import atomic_path

    fig, ax = plt.subplots(figsize=(5, 5), dpi=100)
    cx, cy = plot.centre_xy
    ax.add_patch(Circle((cx, cy), plot.radius_m, fill=False, color="0.5", lw=1))
    names = sorted({str(t.species or t.source) for t in plot.trees})
    colours = {n: plt.cm.tab10(i % 10) for i, n in enumerate(names)}
    for t in plot.trees:
        d = t.dbh_m or 0.2
        key = str(t.species or t.source)
        ax.add_patch(Circle((t.x_m, t.y_m), 2.5 * d, color=colours[key], alpha=0.8))
        ax.annotate(str(t.tree_id), (t.x_m, t.y_m), fontsize=6, ha="center", va="center")
    for n_, c in colours.items():
        ax.plot([], [], "o", color=c, label=n_)
    ax.legend(loc="upper right", fontsize=7)
    r = plot.radius_m * 1.05
    ax.set_xlim(cx - r, cx + r)
    ax.set_ylim(cy - r, cy + r)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or f"{len(plot.trees)} trees (circles 5 × DBH)", fontsize=9)
    fig.tight_layout()
    p = Path(path)
    with atomic_path(p) as tmp:
        fig.savefig(tmp, format="png")
    plt.close(fig)
    return p
