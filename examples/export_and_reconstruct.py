"""Export a sensor model, simulate one frame of a touch and reconstruct it with one-step Tikhonov.

    python examples/export_and_reconstruct.py                 # 4 mm mesh, writes sensor.npz here
    python examples/export_and_reconstruct.py --mesh-size 6 --out /tmp/sensor.npz

The touch is a conductivity disc (the paper's reconstruction data), 20 mm across at 0.3 sigma0, centred at
(30, 65) mm; the script prints where the reconstructed image changes most.
"""

import argparse

import numpy as np

from latticeopt import LatticeDesign, MeshSettings, export_sensor_model, load_sensor_model
from latticeopt.recon import LinearReconstructor, relative_change, render_touches
from latticeopt.sensor_model import SensorSimulator

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--out", default="sensor.npz", help="sensor-model file to write (.npz)")
parser.add_argument("--mesh-size", type=float, default=4.0, help="mesh element size (mm), default 4")
args = parser.parse_args()

path = export_sensor_model(LatticeDesign(width_mm=4, thickness_mm=3), args.out, MeshSettings(size_mm=args.mesh_size))
model = load_sensor_model(path)                         # numpy only; what a reconstruction program reads
print(f"wrote {path}: {model.n_rows} rows, {model.n_pixels} x {model.n_pixels} pixels")

# One frame: the voltages of the sensor with a disc of lower conductivity (x, y, diameter mm, sigma / sigma0).
image = render_touches(np.array([[30.0, 65.0, 20.0, 0.3]]), model.sigma0_S_per_m, model.n_pixels, model.extent_mm)
frame = SensorSimulator(model).voltages(image)
y = relative_change(frame, model.v_ref)                 # (V - V_ref) / V_ref per row

recon = LinearReconstructor(model, "laplacian")         # one-step Tikhonov, Laplacian prior
x, lam = recon.solve(y, 1e-3 * recon.eigenvalues.max())  # lambda relative to the largest eigenvalue
image = x[0]                                            # normalized conductivity change per pixel
i = int(np.argmax(np.abs(image)))
cx, cy = model.pixel_centres_mm()[i]
print(f"largest change {image[i]:+.3g} at ({cx:.1f}, {cy:.1f}) mm; the disc is centred at (30, 65) mm")
