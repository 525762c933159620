"""Pictures of the pipeline, by what they show: raster primitives (:mod:`~ttc.draw.raster`),
overlays on a camera image (:mod:`~ttc.draw.overlays`), the bird's-eye view
(:mod:`~ttc.draw.top_view`) a frame pair's matches (:mod:`~ttc.draw.matches`) and the readable lead-box picture of a
way-off frame (:mod:`~ttc.draw.lead_pair`).

Arrays in, a new BGR uint8 image out; nothing is estimated here (the marks of a top view and
the lead box are given) and nothing is written (the writers in :mod:`experiments.report` and
:mod:`experiments.tools.show` encode and save). Use the names exported here
(``from ttc import draw; draw.top_view(...)``).
"""

from ttc.draw.lead_pair import lead_match_picture
from ttc.draw.matches import draw_box_matches, draw_keypoint_matches
from ttc.draw.overlays import (
    box_labels,
    draw_boxes,
    draw_frame_boxes,
    draw_lead_ttc,
    draw_lidar_on_image,
    format_ttc,
    ttc_lines,
)
from ttc.draw.raster import (
    BOX_COLOUR,
    HIGHLIGHT_COLOUR,
    KEPT_COLOUR,
    PALETTE,
    REMOVED_COLOUR,
    UNMATCHED_COLOUR,
    distance_colours,
    draw_distance_legend,
    palette_colour,
    put_lines,
    put_text,
    splat,
    stack,
    text_band,
)
from ttc.draw.top_view import World, cloud_summary, top_view, world_to_pixel

__all__ = [
    "BOX_COLOUR",
    "HIGHLIGHT_COLOUR",
    "KEPT_COLOUR",
    "PALETTE",
    "REMOVED_COLOUR",
    "UNMATCHED_COLOUR",
    "World",
    "box_labels",
    "cloud_summary",
    "distance_colours",
    "draw_box_matches",
    "draw_boxes",
    "draw_distance_legend",
    "draw_frame_boxes",
    "draw_keypoint_matches",
    "draw_lead_ttc",
    "draw_lidar_on_image",
    "format_ttc",
    "lead_match_picture",
    "palette_colour",
    "put_lines",
    "put_text",
    "splat",
    "stack",
    "text_band",
    "top_view",
    "ttc_lines",
    "world_to_pixel",
]
