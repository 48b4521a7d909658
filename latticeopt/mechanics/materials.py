"""Nearly incompressible neo-Hookean materials of the sensor stack, one per region.

Strain energy per unit reference volume (decoupled form, lengths mm, stresses MPa = N/mm^2)::

    W(F) = mu / 2 (J^(-2/3) I1 - 3) + U(J),    U(J) = kappa / 4 (J^2 - 1 - 2 ln J)

with ``I1 = tr(F^T F)`` and ``J = det F``. ``U`` is convex and grows without bound as ``J -> 0``, so the
stored energy itself resists element inversion. At small strain it reduces to linear elasticity with shear
modulus ``mu`` and bulk modulus ``kappa = 2 mu (1 + nu) / (3 (1 - 2 nu))``.

Default parameters and their sources
------------------------------------
Silicone (substrate, islands, sealing), Ecoflex 00-30 class:
    shear modulus 23 kPa. Smooth-On's Ecoflex 00-30 technical bulletin gives a 100 % modulus of 10 psi
    (69 kPa); soft-robotics models commonly take that as Young's modulus, i.e. ``G = E / 3 = 23 kPa`` for
    an incompressible rubber. Initial shear moduli from hyperelastic fits of Ecoflex 00-30 lie roughly
    between 17 and 35 kPa (range collected in the project's NOTES; for such characterisations of the
    Ecoflex series see Liao, Hossain and Yao, "Ecoflex polymer of different Shore hardnesses: experimental
    investigations and constitutive modelling", Mech. Mater. 144 (2020) 103366). 23 kPa is a mid-range
    value, not a measurement of the paper's material.
Hydrogel (channels), polyacrylamide-LiCl:
    shear modulus 5 kPa. Polyacrylamide ionic conductors of this kind (Keplinger et al., "Stretchable,
    transparent, ionic conductors", Science 341 (2013) 984; PAAm-LiCl: Kim et al., "Highly stretchable,
    transparent ionic touch panel", Science 353 (2016) 682) are soft gels whose shear modulus lies roughly
    between 2 and 15 kPa depending on monomer and cross-linker content (range from the project's NOTES);
    5 kPa sits in that range and is likewise not a measurement of the paper's gel.
Poisson ratio 0.49 for both (``[physics]`` ``hydrogel_poisson_ratio`` and ``silicone_poisson_ratio``):
    rubber is nearly incompressible (bulk modulus ~ 1 GPa, so nu > 0.4999) and a water-swollen gel
    under a fast press (undrained: the water has no time to leave) is too; a slow press lets it drain
    towards the network's own, lower Poisson ratio. 0.49 (``kappa = 50 mu``) keeps the stack nearly
    incompressible yet lets the gel under a deep press lose a third of its volume locally. The patch
    (mean-dilatation) formulation does not lock up to nu = 0.4999 (``benchmarks/bench_locking.py``,
    docs/verification.md), and the indentation converges there (double-precision factorization and
    shifted tangents, :mod:`latticeopt.mechanics.indent`) at several times the cost of 0.49.

Every value is a documented parameter: sweep it, never tune it silently to match a figure.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .. import _validate as v
from ..design import REGION_IDS, REGION_NAMES
from ..errors import ParameterError

#: Regions made of silicone (everything but the hydrogel).
SILICONE_REGIONS = ("substrate", "islands", "sealing")


@dataclass(frozen=True)
class NeoHookean:
    """One nearly incompressible neo-Hookean solid.

    Parameters
    ----------
    shear_modulus_kPa
        Initial shear modulus ``mu`` (kPa), > 0.
    poisson_ratio
        Small-strain Poisson ratio ``nu`` in ``(-1, 0.5)``; sets the bulk modulus.
    """

    shear_modulus_kPa: float
    poisson_ratio: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "shear_modulus_kPa", v.real(
            "shear_modulus_kPa", self.shear_modulus_kPa, lo=0, lo_open=True, hi=1e7))
        object.__setattr__(self, "poisson_ratio", v.real(
            "poisson_ratio", self.poisson_ratio, lo=0, hi=0.5, hi_open=True,
            expected="0 <= poisson_ratio < 0.5 (0.5 itself would need an infinite bulk modulus)"))

    @property
    def mu_MPa(self) -> float:
        return self.shear_modulus_kPa * 1e-3

    @property
    def kappa_MPa(self) -> float:
        """Small-strain bulk modulus (MPa)."""
        nu = self.poisson_ratio
        return self.mu_MPa * 2.0 * (1.0 + nu) / (3.0 * (1.0 - 2.0 * nu))

    @property
    def youngs_modulus_kPa(self) -> float:
        return 2.0 * self.shear_modulus_kPa * (1.0 + self.poisson_ratio)


def _silicone() -> NeoHookean:
    return NeoHookean(shear_modulus_kPa=23.0, poisson_ratio=0.49)


def _hydrogel() -> NeoHookean:
    return NeoHookean(shear_modulus_kPa=5.0, poisson_ratio=0.49)


@dataclass(frozen=True)
class Materials:
    """Material of every region of the stack (defaults and sources: module docstring).

    Parameters
    ----------
    silicone
        Substrate, islands and sealing layer.
    hydrogel
        The conductive channels (or the whole conductive layer for ``w = 0``).
    """

    silicone: NeoHookean = field(default_factory=_silicone)
    hydrogel: NeoHookean = field(default_factory=_hydrogel)

    def __post_init__(self) -> None:
        for name in ("silicone", "hydrogel"):
            if not isinstance(getattr(self, name), NeoHookean):
                raise ParameterError(name, "a NeoHookean(shear_modulus_kPa, poisson_ratio)", getattr(self, name))

    @classmethod
    def uniform(cls, material: NeoHookean) -> Materials:
        """Every region made of ``material`` (a homogeneous block, for verification)."""
        return cls(silicone=material, hydrogel=material)

    def of_region(self, region_id: int) -> NeoHookean:
        name = REGION_NAMES[int(region_id)]
        return self.hydrogel if name == "hydrogel" else self.silicone

    def moduli_MPa(self, region: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Shear and bulk modulus (MPa) of every tet, two arrays of shape ``(M,)`` for region ids ``(M,)``."""
        mu = np.empty(len(region))
        kappa = np.empty(len(region))
        for rid in REGION_IDS.values():
            sel = region == rid
            mat = self.of_region(rid)
            mu[sel], kappa[sel] = mat.mu_MPa, mat.kappa_MPa
        return mu, kappa

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)
