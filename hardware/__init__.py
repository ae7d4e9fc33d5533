"""SCET's prototype (paper Sec. 4), installed as ``scet_hardware``: the Arduino strobe
firmware and its host protocol, the Raspberry Pi capture program and dataset replay, the
wire-wound mirror, and the OV5647 profiles with a strobe planner. See hardware/README.md.

The estimator never imports this package; it reads the capture folders itself
(:mod:`estimator.capture`)."""

from .firmware import (F_CPU_HZ, FirmwareError, PulseTrain, SimulatedBoard, build_firmware,
                       find_toolchain, pulse_train, read_vcd, run_script)
from .mirror import MirrorParams, light_list_toml, mirror_mesh, turn_positions_local_m, write_mirror
from .profiles import PROFILES, RealisedPlan, SensorProfile, plan_prototype_strobe, profile
from .strobe import (StrobeCount, StrobeError, StrobeLink, StrobeReplyError, StrobeSettings,
                     StrobeTimeout, parse_count, parse_reply, parse_settings)

__all__ = ["F_CPU_HZ", "FirmwareError", "PulseTrain", "SimulatedBoard", "build_firmware",
           "find_toolchain", "pulse_train", "read_vcd", "run_script", "MirrorParams",
           "light_list_toml", "mirror_mesh", "turn_positions_local_m", "write_mirror", "PROFILES",
           "RealisedPlan", "SensorProfile", "plan_prototype_strobe", "profile", "StrobeCount",
           "StrobeError", "StrobeLink", "StrobeReplyError", "StrobeSettings", "StrobeTimeout",
           "parse_count", "parse_reply", "parse_settings"]
