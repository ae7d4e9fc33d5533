"""The lighting designer: light layouts that put enough glints in every band (``scet
design-lights``; SCET paper Sec. 5 and 5.1, "a grid of point source illuminators to generate
enough glints in one band").

Modules: :mod:`.region` (where lights may sit, what blocks a glint), :mod:`.families` (arcs
of evenly spaced lights), :mod:`.objective` (glints per band, and the tracker's matcher on
them), :mod:`.search` (differential evolution, then free lights), :mod:`.report` (the scene
file and the report), :mod:`.wire` (the wire style's arcs as wire-wound mirrors with their
LEDs), :mod:`.wire_led` and :mod:`.wire_report` (where to put a wire mirror's LED).
"""

from .families import Arc, ArcFamily, share_counts
from .objective import (BandModel, DesignPoses, LayoutScore, band_counts, band_model,
                        counted_share, design_poses, evaluate_layout, layout_glints,
                        setup_layout_glints, with_lights)
from .region import Region, admissible, glint_unblocked, in_screen_view, sample_region, scene_shells
from .report import designed_scene_text, report_markdown, write_design
from .search import Budget, DesignResult, SearchSettings, coverage_bound, design_lights
from .wire import arc_mirror, centred_led, wire_groups, wire_mirror_table

__all__ = ["Arc", "ArcFamily", "share_counts", "BandModel", "DesignPoses", "LayoutScore",
           "band_counts", "band_model", "counted_share", "design_poses", "evaluate_layout",
           "layout_glints", "setup_layout_glints", "with_lights", "Region", "admissible", "glint_unblocked",
           "in_screen_view", "sample_region", "scene_shells", "designed_scene_text",
           "report_markdown", "write_design", "Budget", "DesignResult", "SearchSettings",
           "coverage_bound", "design_lights", "arc_mirror", "centred_led", "wire_groups",
           "wire_mirror_table"]
