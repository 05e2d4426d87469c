"""Handles, pins, control meshes, starts, the `Rig`, its stacks and size ladder."""

from ._control import (
    AbstractControl as AbstractControl,
    FullSolve as FullSolve,
    GivenControl as GivenControl,
    PaperControl as PaperControl,
)
from ._handles import (
    Bone as Bone,
    Handles as Handles,
    make_handles as make_handles,
    parse_handles as parse_handles,
    pin as pin,
)
from ._ladder import SizeLadder as SizeLadder, padded_twin as padded_twin
from ._pins import (
    pin_state as pin_state,
    pinned_row as pinned_row,
    with_pin_state as with_pin_state,
    with_rows as with_rows,
)
from ._posable import AbstractRig as AbstractRig, ControlMesh as ControlMesh, ShapeMesh as ShapeMesh
from ._rig import (
    Rig as Rig,
    shape_thickness as shape_thickness,
    solve_in_frame as solve_in_frame,
)
from ._stack import pad_rows as pad_rows, stacked as stacked, too_large as too_large
from ._start import (
    AbstractStart as AbstractStart,
    Init as Init,
    RestStart as RestStart,
    RigidStart as RigidStart,
    TurnedStart as TurnedStart,
    checked_start as checked_start,
)
