"""One press into the paper's optimum design: indentation, current flow on the deformed gel, V_rel.

    python examples/simulate_press.py            # 2 mm mesh (the converged default), about half a minute
    python examples/simulate_press.py --mesh-size 6   # coarse mesh, a few seconds
"""

import argparse

from latticeopt import CoupledModel, LatticeDesign, MeshSettings, Touch

parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
parser.add_argument("--mesh-size", type=float, default=2.0, help="mesh element size (mm), default 2")
parser.add_argument("--rim", default="none", choices=["none", "channel"], help="rim layout, default none")
args = parser.parse_args()

design = LatticeDesign(width_mm=4, thickness_mm=3, rim=args.rim)     # square lattice, w = 4 mm, t = 3 mm
model = CoupledModel(design, MeshSettings(size_mm=args.mesh_size))        # meshes once, solves the untouched sensor
result = model.simulate([Touch(x_mm=50, y_mm=50, radius_mm=8.75, depth_mm=4.0)])   # flat punch, 4 mm deep
print(design.describe())
print(f"V_rel = {result.v_rel:.4f}, punch force {sum(result.forces_N):.3f} N")
