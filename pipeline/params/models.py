"""Parameters of the tree model library's commands: procedural trees and QSM meshes."""

from __future__ import annotations

from dataclasses import dataclass

from ._fields import check_bounds, param

__all__ = ["JOINTS", "ModelParams"]

#: How cylinder tables become meshes: one closed prism per cylinder, or one crack-free
#: mitred tube per branch.
JOINTS: tuple[str, ...] = ("separate", "miter")


@dataclass(frozen=True, kw_only=True)
class ModelParams:
    """How a tree model is generated and meshed (``treesim model ...``).

    Parameters
    ----------
    species : str, optional
        A tree species (:data:`treesim.models.SPECIES`).
    seed : int
        Seed of the procedural tree.
    leaves : bool, optional
        Add leaves, or not; ``None``: the species' own choice.
    facets : int
        Vertices per ring of the wood mesh.
    joints : {"miter", "separate"}
        miter: one crack-free tube per branch, starting inside its parent (a plug
        sunk into the parent closes the junction, as reconstruct meshes its own
        tables); separate: a closed prism per cylinder.
    """

    species: str | None = param(None, help="tree species (see 'treesim model list')")
    seed: int = param(0, help="random seed of the procedural tree", ge=0)
    leaves: bool | None = param(
        None, help="add leaves, or not", none_means="the species' own choice"
    )
    facets: int = param(32, help="vertices per ring of the wood mesh", ge=3)
    joints: str = param(
        "miter",
        help="miter: one crack-free tube per branch, its start sunk into its parent; "
        "separate: a closed prism per cylinder",
        choices=JOINTS,
    )

    def __post_init__(self) -> None:
        check_bounds(self)
