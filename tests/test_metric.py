"""V_rel (paper eq. 5) with an instrument floor: its partials against central differences, what the floor does to
rows at round-off, and the dead-end corner rows of the diagonal lattice that make the floor necessary."""

import subprocess
import sys

import numpy as np
import pytest

from latticeopt import LatticeDesign, MeshSettings
from latticeopt.coupled import PhysicsSettings
from latticeopt.density import DensityModel
from latticeopt.electrics.forward import ForwardModel
from latticeopt.errors import ParameterError
from latticeopt.mesh import mesh_design
from latticeopt.metric import relative_change, relative_change_partials, smallest_reference_rel
from latticeopt.touches import Touch


def _voltages(seed: int, n: int = 40):
    rng = np.random.default_rng(seed)
    ref = rng.choice([-1.0, 1.0], n) * 10.0 ** rng.uniform(-3, 0, n)
    return ref * (1 + 0.2 * rng.standard_normal(n)), ref


@pytest.mark.parametrize("floor_rel", [0.0, 0.05])
def test_partials_match_central_differences(floor_rel):
    v, ref = _voltages(3)
    if floor_rel:  # rows both sides of the floor, none within the step of it
        mag = np.abs(ref) / np.abs(ref).max()
        assert (mag < 0.9 * floor_rel).sum() >= 5 and (mag > 1.1 * floor_rel).sum() >= 5
    value, dv, dref = relative_change_partials(v, ref, floor_rel)
    assert value == relative_change(v, ref, floor_rel)
    h = 1e-7
    for i in range(len(v)):
        e = np.zeros(len(v))
        e[i] = h * max(abs(v[i]), 1e-3)
        fd_v = (relative_change(v + e, ref, floor_rel) - relative_change(v - e, ref, floor_rel)) / (2 * e[i])
        fd_r = (relative_change(v, ref + e, floor_rel) - relative_change(v, ref - e, floor_rel)) / (2 * e[i])
        assert dv[i] == pytest.approx(fd_v, rel=1e-5, abs=1e-8)
        assert dref[i] == pytest.approx(fd_r, rel=1e-5, abs=1e-8)


def test_floor_keeps_round_off_rows_from_carrying_the_mean():
    v, ref = _voltages(5)
    plain = relative_change(v, ref)
    # two rows at round-off whose "change" is round-off too: eq. 5 reads a ratio of noise in them
    ref2, v2 = np.append(ref, [3e-16, -2e-16]), np.append(v, [4e-15, 1e-16])
    noisy = relative_change(v2, ref2)
    assert noisy > 3 * plain
    assert relative_change(v, ref, 1e-4) == plain  # every row of the set lies above that floor
    # each round-off row counts a change of ~4e-15 against a floor of 1e-4 * max|ref|: nothing
    assert relative_change(v2, ref2, 1e-4) == pytest.approx(plain * len(v) / len(v2), rel=1e-9)
    assert smallest_reference_rel(ref2) < 1e-14 < smallest_reference_rel(ref)


def test_floor_is_validated_with_its_key():
    with pytest.raises(ParameterError, match=r"^measurement_floor_rel: "):
        PhysicsSettings(measurement_floor_rel=0.5)
    done = subprocess.run([sys.executable, "-m", "latticeopt", "indent", "--touch", "50,50,8.75,4",
                           "--physics", "measurement_floor_rel=-1"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and "measurement_floor_rel" in done.stderr and "Traceback" not in done.stderr


@pytest.mark.parametrize("width_mm, dead", [(3.0, True), (4.75, False)])
def test_diagonal_corner_channel_is_a_dead_end_below_the_electrode(width_mm, dead):
    """The diagonal lattice (p = 12.5 mm, no rim channel) joins the two electrodes by each corner with one short
    channel that meets the network at a single crossing until w reaches the next line (at w = 4.75 that line
    reaches the electrodes too). With the current driven elsewhere the pair is at one potential: its rows are
    round-off, on any mesh; the square lattice's are not."""
    design = LatticeDesign(pattern="diagonal", width_mm=width_mm, thickness_mm=3.0, pitch_mm=12.5)
    fwd = ForwardModel(mesh_design(design, MeshSettings(size_mm=4.0, channel_cells=1), cache_dir=False))
    smallest = smallest_reference_rel(fwd.voltages)
    assert (smallest < 1e-6) == dead, smallest


def test_density_gradient_carries_the_floor():
    """The density model's adjoint V_rel gradient with a floor (rows below 5 % of the largest floored) against
    central differences."""
    n, h = 6, 1e-4
    physics = PhysicsSettings(mechanics_rtol=1e-10, measurement_floor_rel=0.05)
    model = DensityModel(LatticeDesign(thickness_mm=3.0), n, MeshSettings(size_mm=8.0), physics)
    press = [[Touch(40.0, 55.0, 12.0, 2.5)]]
    rng = np.random.default_rng(2)
    d = 0.3 + 0.4 * rng.random((n, n))
    ev = model.evaluate(d, press)
    ref = ev.reference_voltages
    assert (np.abs(ref) < 0.05 * np.abs(ref).max()).any()  # the floor is in play
    direction = rng.standard_normal((n, n))
    fd = (model.evaluate(d + h * direction, press, gradient=False).v_rel
          - model.evaluate(d - h * direction, press, gradient=False).v_rel) / (2 * h)
    assert float(np.sum(ev.dv_rel_ddensity * direction)) == pytest.approx(fd, rel=1e-4)
