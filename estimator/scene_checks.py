"""The scene loader's geometry checks (:func:`estimator.scene.parse_scene`): what no key alone
can catch, a camera or a light inside the eye, or a camera that cannot see the cornea. ``top``
is the loader's table reader; every problem raises its :class:`~estimator.errors.SceneError`
naming the key.
"""

from __future__ import annotations

import numpy as np

#: Clearance (m) beyond the cornea's reach at any gaze: nearer than that is inside the eye.
_EYE_CLEARANCE_M = 0.5e-3


def check_geometry(setup, top) -> None:
    """Refuse a scene whose camera or lights sit inside the eye, whose lights are not finite,
    or whose camera cannot see the front of the cornea: ``top.error`` (the scene loader's
    :class:`~estimator.errors.SceneError`) names the key."""
    eye, cam = setup.eye, setup.camera
    # Anything within reach of the cornea at any gaze (apex sphere) is inside the eye.
    reach = eye.cornea_offset_m + eye.cornea_radius_m + _EYE_CLEARANCE_M
    d_cam = np.linalg.norm(cam.position_m - eye.rotation_center_m)
    if d_cam <= reach:
        raise top.error("camera.position_m", f"camera {d_cam * 1e3:.2f} mm from the eye's rotation "
                                             f"centre, inside the eye (needs > {reach * 1e3:.2f} mm)")
    lights = setup.lights.positions_world_m
    d_l = np.linalg.norm(lights - eye.rotation_center_m, axis=1)
    if np.any(d_l <= reach):
        i = int(np.argmin(d_l))
        g = int(setup.lights.group_index[i])
        first = sum(grp.count for grp in setup.lights.groups[:g])
        raise top.error(f"lights[{g}]", f"light {i - first} of this group (light {i} overall) lies {d_l[i] * 1e3:.2f} mm from the eye's rotation "
                                  f"centre, inside the eye (needs > {reach * 1e3:.2f} mm)")
    if not np.all(np.isfinite(lights)):
        raise top.error("lights", "light positions are not finite")
    apex_px, depth = cam.project(eye.apex())
    center_px, _ = cam.project(eye.cornea_center(0.0, 0.0))
    if not (depth > 0 and cam.in_image(apex_px)):
        raise top.error("camera", "the camera cannot see the cornea: the corneal apex at primary "
                                  f"gaze projects to {np.round(apex_px, 1)}, outside the "
                                  f"{cam.width_px}x{cam.height_px} image or behind the camera")
    if not np.all(np.isfinite(center_px)):
        raise top.error("camera", "the camera cannot see the cornea (cornea centre behind it)")
    # The camera must face the front of the cornea: the apex at primary gaze must be on the
    # camera's side of the corneal sphere (a camera behind or beside the eye sees no glints).
    axis = eye.apex() - eye.cornea_center(0.0, 0.0)
    axis /= np.linalg.norm(axis)
    if (cam.position_m - eye.cornea_center(0.0, 0.0)) @ axis <= eye.cornea_radius_m:
        raise top.error("camera.position_m", "the camera cannot see the cornea: it must sit in front of "
                                             "the corneal apex (the eye looks along -z), got "
                                             f"{np.round(cam.position_m, 4).tolist()} m")
