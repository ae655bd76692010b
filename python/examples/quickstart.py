"""The README's Python example: encode a numpy field, decode it at twice the
resolution, plot a slice (needs matplotlib). Writes quickstart.png."""
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

import gsenc

# A 64^3 field, [z][y][x]: a wavy shell around a dense core.
z, y, x = np.mgrid[0:64, 0:64, 0:64] / 63.0 - 0.5
r = np.sqrt(x**2 + y**2 + z**2)
field = np.exp(-((r - 0.3 - 0.04 * np.sin(8 * np.arctan2(y, x))) / 0.05) ** 2) + 2 * np.exp(-(r / 0.08) ** 2)

model = gsenc.encode_grid(field, 2000, schedule="tuned", payload="packed", progress=True)
print(f"{len(model)} Gaussians, {model.psnr:.1f} dB, {model.write('shell.gsm')} bytes")

fine = gsenc.read("shell.gsm").decode(dims=(128, 128, 128))  # float32 [z][y][x]
fig, ax = plt.subplots(1, 2, figsize=(9, 4.2))
ax[0].imshow(field[32], origin="lower", cmap="viridis")
ax[0].set_title("field, 64² slice")
ax[1].imshow(fine[64], origin="lower", cmap="viridis")
ax[1].set_title(f"gsenc, decoded at 128² ({model.psnr:.1f} dB)")
fig.savefig("quickstart.png", dpi=80, bbox_inches="tight")
