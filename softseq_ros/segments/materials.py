"""
Incompressible hyperelastic laws, reduced to equibiaxial stretch.

A thin membrane inflated into a sphere (a balloon, or the pole of a bulging cap) is stretched
equally in its two in-plane directions by ``lambda`` and thinned by ``lambda**-2``. Every law here
is therefore exposed through the strain energy per unit reference volume of that state,
``W(lambda) = W_3d(lambda, lambda, lambda**-2)``, and its derivative ``dW/dlambda``. Both are in
pascals. The membrane tension (force per unit current length) is
``N = H / (2 * lambda) * dW/dlambda`` for a reference thickness ``H``.
"""

from dataclasses import dataclass, field, fields
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from softseq_ros.segments.identity import exact, exact_list

# A polynomial root whose imaginary part is below this is a real stretch (numpy's roots
# leave round-off there).
REAL_ROOT_IMAG = 1e-9


class Material(Protocol):
    """What the membrane models need from a material law."""

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Strain energy per reference volume under equibiaxial stretch, in Pa."""
        ...

    def energy_derivative(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """D(energy)/d(stretch), in Pa."""
        ...

    @property
    def shear_modulus(self) -> float:
        """Initial shear modulus, in Pa."""
        ...

    @property
    def max_stretch(self) -> float:
        """Largest equibiaxial stretch the law is defined for (inf when unbounded)."""
        ...


# A stretch given as a float stays one (a single volume, as the fluid network asks thousands
# of times): numpy's handling of a scalar costs ten times the arithmetic.
def _as_stretch(stretch: ArrayLike) -> float | NDArray[np.float64]:
    return float(stretch) if isinstance(stretch, float) else np.asarray(stretch, dtype=float)


def _invariants(stretch: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    lam = _as_stretch(stretch)
    return _first_invariant(lam), lam**4 + 2.0 * lam**-2


# The laws that need I1 alone skip I2: its two powers cost as much as I1 and the laws are
# evaluated millions of times per equilibrium map.
def _first_invariant(stretch: ArrayLike) -> NDArray[np.float64]:
    lam = _as_stretch(stretch)
    return 2.0 * lam**2 + lam**-4


def _di1(stretch: ArrayLike) -> NDArray[np.float64]:
    lam = _as_stretch(stretch)
    return 4.0 * lam - 4.0 * lam**-5


def _di2(stretch: ArrayLike) -> NDArray[np.float64]:
    lam = _as_stretch(stretch)
    return 4.0 * lam**3 - 4.0 * lam**-3


@dataclass(frozen=True)
class NeoHookean:
    """W = mu/2 (I1 - 3)."""

    mu: float

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Strain energy per reference volume, in Pa."""
        i1 = _first_invariant(stretch)
        return 0.5 * self.mu * (i1 - 3.0)

    def energy_derivative(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """D(energy)/d(stretch), in Pa."""
        return 0.5 * self.mu * _di1(stretch)

    @property
    def shear_modulus(self) -> float:
        """Initial shear modulus, in Pa."""
        return self.mu

    @property
    def max_stretch(self) -> float:
        """Unbounded."""
        return np.inf


@dataclass(frozen=True)
class MooneyRivlin:
    """W = C1 (I1 - 3) + C2 (I2 - 3)."""

    c1: float
    c2: float

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Strain energy per reference volume, in Pa."""
        i1, i2 = _invariants(stretch)
        return self.c1 * (i1 - 3.0) + self.c2 * (i2 - 3.0)

    def energy_derivative(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """D(energy)/d(stretch), in Pa."""
        return self.c1 * _di1(stretch) + self.c2 * _di2(stretch)

    @property
    def shear_modulus(self) -> float:
        """Initial shear modulus, in Pa."""
        return 2.0 * (self.c1 + self.c2)

    @property
    def max_stretch(self) -> float:
        """Unbounded."""
        return np.inf


@dataclass(frozen=True)
class Gent:
    """W = -mu Jm / 2 ln(1 - (I1 - 3) / Jm): locks when I1 - 3 reaches Jm."""

    mu: float
    jm: float

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Strain energy per reference volume, in Pa."""
        i1 = _first_invariant(stretch)
        return -0.5 * self.mu * self.jm * np.log1p(-(i1 - 3.0) / self.jm)

    def energy_derivative(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """D(energy)/d(stretch), in Pa."""
        i1 = _first_invariant(stretch)
        return 0.5 * self.mu * _di1(stretch) / (1.0 - (i1 - 3.0) / self.jm)

    @property
    def shear_modulus(self) -> float:
        """Initial shear modulus, in Pa."""
        return self.mu

    @property
    def max_stretch(self) -> float:
        """Stretch at which I1 - 3 = Jm (2 lam^6 - (Jm + 3) lam^4 + 1 = 0, largest root)."""
        roots = np.roots([2.0, 0.0, -(self.jm + 3.0), 0.0, 0.0, 0.0, 1.0])
        real = roots[np.abs(roots.imag) < REAL_ROOT_IMAG].real
        return float(real[real > 1.0].max())


@dataclass(frozen=True)
class Ogden:
    """W = sum_i mu_i / alpha_i (l1^a_i + l2^a_i + l3^a_i - 3); shear modulus sum(mu_i a_i) / 2."""

    mus: tuple[float, ...]
    alphas: tuple[float, ...]

    def __post_init__(self) -> None:
        """Check that every term has a modulus and an exponent."""
        if len(self.mus) != len(self.alphas) or not self.mus:
            raise ValueError('Ogden needs as many moduli as exponents, at least one')
        if any(a == 0.0 for a in self.alphas):
            raise ValueError('Ogden exponents must be non-zero')

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Strain energy per reference volume, in Pa."""
        lam = np.asarray(stretch, dtype=float)
        return sum(m / a * (2.0 * lam**a + lam ** (-2.0 * a) - 3.0)
                   for m, a in zip(self.mus, self.alphas))

    def energy_derivative(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """D(energy)/d(stretch), in Pa."""
        lam = np.asarray(stretch, dtype=float)
        return sum(2.0 * m * (lam ** (a - 1.0) - lam ** (-2.0 * a - 1.0))
                   for m, a in zip(self.mus, self.alphas))

    @property
    def shear_modulus(self) -> float:
        """Initial shear modulus, in Pa."""
        return 0.5 * sum(m * a for m, a in zip(self.mus, self.alphas))

    @property
    def max_stretch(self) -> float:
        """Unbounded."""
        return np.inf


# Abaqus' five-term expansion of the inverse Langevin function (Abaqus Theory Manual 4.6.1).
_ARRUDA_BOYCE_C = (1.0 / 2.0, 1.0 / 20.0, 11.0 / 1050.0, 19.0 / 7000.0, 519.0 / 673750.0)


@dataclass(frozen=True)
class ArrudaBoyce:
    """Abaqus form: W = mu sum_{i=1..5} C_i / lambda_m^(2i-2) (I1^i - 3^i)."""

    mu: float
    lambda_m: float

    def _terms(self) -> list[tuple[int, float]]:
        return [(i, c / self.lambda_m ** (2 * i - 2))
                for i, c in enumerate(_ARRUDA_BOYCE_C, start=1)]

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Strain energy per reference volume, in Pa."""
        i1 = _first_invariant(stretch)
        return self.mu * sum(c * (i1**i - 3.0**i) for i, c in self._terms())

    def energy_derivative(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """D(energy)/d(stretch), in Pa."""
        i1 = _first_invariant(stretch)
        dw_di1 = self.mu * sum(i * c * i1 ** (i - 1) for i, c in self._terms())
        return dw_di1 * _di1(stretch)

    @property
    def shear_modulus(self) -> float:
        """Initial shear modulus, in Pa (mu times Abaqus' series factor at I1 = 3)."""
        return float(2.0 * self.mu * sum(i * c * 3.0 ** (i - 1) for i, c in self._terms()))

    @property
    def max_stretch(self) -> float:
        """Unbounded (the truncated series does not lock)."""
        return np.inf


@dataclass(frozen=True)
class Yeoh:
    """W = C1 (I1 - 3) + C2 (I1 - 3)^2 + C3 (I1 - 3)^3."""

    c1: float
    c2: float
    c3: float = 0.0

    def energy(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """Strain energy per reference volume, in Pa."""
        i1 = _first_invariant(stretch)
        x = i1 - 3.0
        return self.c1 * x + self.c2 * x**2 + self.c3 * x**3

    def energy_derivative(self, stretch: ArrayLike) -> NDArray[np.float64]:
        """D(energy)/d(stretch), in Pa."""
        i1 = _first_invariant(stretch)
        x = i1 - 3.0
        return (self.c1 + 2.0 * self.c2 * x + 3.0 * self.c3 * x**2) * _di1(stretch)

    @property
    def shear_modulus(self) -> float:
        """Initial shear modulus, in Pa."""
        return 2.0 * self.c1

    @property
    def max_stretch(self) -> float:
        """Unbounded."""
        return np.inf


@dataclass(frozen=True)
class MaterialSpec:
    """A law name and its parameters, as a scene file gives them."""

    law: str
    params: dict[str, float] = field(default_factory=dict)


_LAWS = {
    'neo_hookean': (NeoHookean, ('shear_modulus_pa',)),
    'mooney_rivlin': (MooneyRivlin, ('c1_pa', 'c2_pa')),
    'gent': (Gent, ('shear_modulus_pa', 'jm')),
    'ogden': (Ogden, ('mu_pa', 'alpha')),
    'arruda_boyce': (ArrudaBoyce, ('shear_modulus_pa', 'lambda_m')),
    'yeoh': (Yeoh, ('c1_pa', 'c2_pa', 'c3_pa')),
}

LAW_NAMES = tuple(_LAWS)


def material_parameter_names(law: str) -> tuple[str, ...]:
    """Parameter names (with their units) that ``make_material`` expects for ``law``."""
    if law not in _LAWS:
        raise ValueError(f'unknown material law {law!r}; known: {", ".join(LAW_NAMES)}')
    return _LAWS[law][1]


def make_material(law: str, params: dict[str, object]) -> Material:
    """
    Build a material law from the names a scene file uses.

    Ogden takes lists ``mu_pa`` and ``alpha``; every other law takes scalars. Raises ValueError
    naming the missing or unknown parameter.
    """
    names = material_parameter_names(law)
    missing = [n for n in names if n not in params and not (law == 'yeoh' and n == 'c3_pa')]
    if missing:
        raise ValueError(f'material {law!r} is missing {", ".join(missing)}')
    unknown = sorted(set(params) - set(names))
    if unknown:
        raise ValueError(f'material {law!r} has unknown parameter(s) {", ".join(unknown)}; '
                         f'expected {", ".join(names)}')
    cls = _LAWS[law][0]
    if law == 'ogden':
        mus = params['mu_pa']
        alphas = params['alpha']
        mus = tuple(float(m) for m in (mus if isinstance(mus, list) else [mus]))
        alphas = tuple(float(a) for a in (alphas if isinstance(alphas, list) else [alphas]))
        return Ogden(mus, alphas)
    values = [float(params[n]) for n in names if n in params]
    return cls(*values)


def material_definition(material: Material) -> dict[str, object]:
    """
    The law and its parameters as a scene file names them (``{'law': 'gent', 'jm': 30.0, ...}``).

    Exact values, JSON-able (Ogden's terms as lists): what defines the material, for digests.
    Raises TypeError for a material that is not one of these laws.
    """
    for law, (cls, names) in _LAWS.items():
        if type(material) is cls:
            values = [getattr(material, f.name) for f in fields(cls)]
            definition: dict[str, object] = {'law': law}
            for name, value in zip(names, values):
                definition[name] = (exact_list(value) if isinstance(value, tuple)
                                    else exact(value))
            return definition
    raise TypeError(f'material {type(material).__name__} is none of the laws '
                    f'{", ".join(LAW_NAMES)}: it cannot say what defines it')
