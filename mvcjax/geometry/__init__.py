"""Shapes, pictures in and out, meshing, topology, mean value and barycentric
coordinates and the skinning that carries points by them: numpy and the meshing
libraries at build time, JAX for what runs per frame."""

from ._coordinates import (
    barycentric_coordinates as barycentric_coordinates,
    locate_points as locate_points,
    mean_value_coordinates as mean_value_coordinates,
    ring_area as ring_area,
    signed_areas as signed_areas,
)
from ._folds import (
    area_along as area_along,
    first_flat as first_flat,
    inverted_count as inverted_count,
)
from ._image import (
    CornerColour as CornerColour,
    cut_out as cut_out,
    image_mask as image_mask,
    load_image as load_image,
)
from ._local_frame import (
    Frame as Frame,
    bounding_frame as bounding_frame,
    check_representable as check_representable,
    frame_array as frame_array,
    points_to_local as points_to_local,
)
from ._meshing import (
    control_polygon as control_polygon,
    counter_clockwise as counter_clockwise,
    inner_control_vertices as inner_control_vertices,
    thin_outline as thin_outline,
    triangulate_control as triangulate_control,
    triangulate_shape as triangulate_shape,
)
from ._metrics import (
    difference as difference,
    flipped_triangles as flipped_triangles,
    smoothness as smoothness,
)
from ._pictures import (
    as_matte_rgb as as_matte_rgb,
    byte_values as byte_values,
    check_channels as check_channels,
    check_values as check_values,
    to_bytes as to_bytes,
    to_uint8 as to_uint8,
)
from ._shape import (
    Shape as Shape,
    pixels_to_points as pixels_to_points,
    points_to_pixels as points_to_pixels,
)
from ._skinning import (
    BLOCK_ROWS as BLOCK_ROWS,
    AbstractSkinning as AbstractSkinning,
    BarycentricSkinning as BarycentricSkinning,
    BlendedMVCSkinning as BlendedMVCSkinning,
    MVCSkinning as MVCSkinning,
    Skinning as Skinning,
    as_skinning as as_skinning,
    block_width_limit as block_width_limit,
    pack_blocks as pack_blocks,
    pack_rows as pack_rows,
    skin_frames_into as skin_frames_into,
    tile_rows as tile_rows,
)
from ._topology import (
    boundary_edges as boundary_edges,
    boundary_loops as boundary_loops,
    edges as edges,
    interior_edges as interior_edges,
    on_boundary as on_boundary,
    vertex_stars as vertex_stars,
)
