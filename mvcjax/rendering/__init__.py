"""Pictures of posed meshes: windows, raster, shading, draw order, the `Renderer`."""

from ._options import (
    AbstractAlpha as AbstractAlpha,
    Checkerboard as Checkerboard,
    GrownWindow as GrownWindow,
    MeshAlpha as MeshAlpha,
    PictureAlpha as PictureAlpha,
)
from ._render import (
    Renderer as Renderer,
    as_picture as as_picture,
    check_drawn_mesh as check_drawn_mesh,
    check_size as check_size,
    check_window as check_window,
    core_depth as core_depth,
    depth_from_handles as depth_from_handles,
    fill_texture as fill_texture,
    fit_window as fit_window,
    in_window as in_window,
    key_layout as key_layout,
    refuse_over_budget as refuse_over_budget,
    render as render,
    spread_from_handles as spread_from_handles,
    to_pixels as to_pixels,
)
