"""
Bands of a strobed rolling-shutter frame
========================================

Which rows each strobe pulse lights (the paper's Eqs. (2)-(8)), for the default scene: 16
pulses of 100 us a frame on the OV5647's VGA timing. No rendering: the timing model alone
(:mod:`estimator.banding`).
"""

import matplotlib.pyplot as plt
import numpy as np

from estimator.banding import band_height, row_pulse_weights
from estimator.scene import load_scene

setup = load_scene("paper_sim")
sensor, strobe = setup.sensor, setup.strobe
print(f"S = {sensor.total_lines} lines, N = {sensor.visible_lines} visible, "
      f"frame {sensor.frame_period_s * 1e3:.3f} ms, exposure {sensor.exposure_s * 1e6:.0f} us")
print(f"Eq. (7) band height: {band_height(sensor, strobe.pulse_s):.1f} rows")

# %%
# Each row collects a share of some pulses: the overlap of its exposure window with each.
pulses, starts_s, weights = row_pulse_weights(sensor, strobe, 0)
rows = np.arange(sensor.visible_lines)
fig, ax = plt.subplots(figsize=(7, 3.2))
for j in range(weights.shape[1]):
    if weights[:, j].max() > 0:
        ax.plot(rows, weights[:, j], lw=1.2)
ax.set_xlabel("image row y")
ax.set_ylabel("share of the pulse")
ax.set_title("one curve per strobe pulse of frame 0")
fig.tight_layout()
