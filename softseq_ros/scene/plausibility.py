"""
The unit checks: numbers a soft segment's curve or a measurement cannot hold in SI units.

A table, a law or an experiment file is given in SI units (m^3, Pa); a number written in mL
or kPa instead is off by 10^6 or 10^3 and would run without a word. These rules catch what no
soft actuator can be, and say which unit was likely meant. Each has its limit, stated with it
(docs/faults.md, "Units and overflow"):

- Volume: a segment holding more than :data:`VOLUME_PER_CUBED_LENGTH` times the cube of its
  length (a balloon three times as wide as it is long) or more than 1 m^3. A table in mL of
  any segment longer than about 1 mm is beyond it, whatever its rest volume.
- Pressure, too small: a table or measured curve whose largest pressure, in magnitude, is
  below :data:`MIN_PRESSURE_PA` (100 Pa, the weight of 1 cm of water). A table in kPa of a
  segment that stays below 100 kPa is caught; one that goes beyond 100 kPa is not, and a real
  segment that never reaches 100 Pa is refused too. Closed-form laws are not held to it: their
  parameters say their unit in their names (``shear_modulus_pa``).
- Pressure, too large or not finite: any segment whose pressure over its volume range leaves
  +-:data:`MAX_PRESSURE_PA` (1 GPa: steel yields at a quarter of that, an elastomer bursts at a
  few MPa) or is not a finite number: a parameter in the wrong unit, or a law that overflows
  (an Ogden exponent of 1000, a modulus of 1e306 Pa).
- Material: a law whose initial shear modulus passes 1 GPa, or whose stress overflows at
  a stretch up to 4 (or just short of its locking stretch): checked where a scene's balloon
  or a FEM design names it, before anything is solved or meshed.
- Absolute pressure: an absolute reading below :data:`MIN_ABSOLUTE_PA` (1 kPa: a liquid boils
  below about 2.3 kPa at room temperature), or an ambient pressure outside 10 kPa to 1 MPa.
"""

import math
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    # For the annotations only: the models import scipy, which the report (reading an
    # experiment file through these rules) must not pay for.
    from softseq_ros.segments.materials import Material
    from softseq_ros.segments.models import Segment

MAX_VOLUME_M3 = 1.0
VOLUME_PER_CUBED_LENGTH = 100.0
MIN_PRESSURE_PA = 100.0
MAX_PRESSURE_PA = 1.0e9
MIN_ABSOLUTE_PA = 1.0e3
AMBIENT_RANGE_PA = (1.0e4, 1.0e6)
# Where a law's curve is looked at: enough to see an overflow anywhere along it.
CURVE_SAMPLES = 513
# A soft segment's membranes stretch a few times at most; a law is looked at up to here.
MATERIAL_STRETCH = 4.0

ML_HINT = 'is it in mL? Volumes are in m^3 (1 mL = 1e-6 m^3)'
KPA_HINT = 'is it in kPa or MPa? Pressures are in Pa (1 kPa = 1000 Pa)'


def volume_problem(largest_m3: float, length_m: float) -> str | None:
    """Why a segment holding ``largest_m3`` cannot be ``length_m`` long, or None."""
    bound = min(MAX_VOLUME_M3, VOLUME_PER_CUBED_LENGTH * length_m ** 3)
    if largest_m3 > bound:
        return (f'the largest volume is {largest_m3:.6g} m^3, more than '
                f'{VOLUME_PER_CUBED_LENGTH:g} times the cube of the segment length '
                f'({length_m:g} m) or 1 m^3 ({bound:.3g} m^3): {ML_HINT}')
    return None


def small_pressure_problem(pressures: NDArray[np.float64]) -> str | None:
    """Why pressures that all stay below 100 Pa in magnitude are not in Pa, or None."""
    largest = float(np.max(np.abs(pressures))) if pressures.size else 0.0
    if largest < MIN_PRESSURE_PA:
        return (f'every pressure is within {MIN_PRESSURE_PA:g} Pa of zero (the largest '
                f'{largest:.6g} Pa; 100 Pa is the weight of 1 cm of water): {KPA_HINT}')
    return None


def curve_problem(segment: 'Segment') -> str | None:
    """Why ``segment``'s pressure curve is no soft segment's (not finite, > 1 GPa), or None."""
    volumes = np.linspace(segment.rest_volume, segment.max_volume, CURVE_SAMPLES)
    with np.errstate(all='ignore'):
        pressures = np.asarray(segment.pressure(volumes), dtype=float)
    bad = ~np.isfinite(pressures)
    if bad.any():
        at = int(np.argmax(bad))
        return (f'its pressure is {pressures[at]} at {volumes[at]:.6g} m^3: the law overflows '
                'there (a parameter in the wrong unit, or beyond any material)')
    at = int(np.argmax(np.abs(pressures)))
    if abs(pressures[at]) > MAX_PRESSURE_PA:
        return (f'its pressure reaches {pressures[at]:.3g} Pa at {volumes[at]:.6g} m^3, beyond '
                f'{MAX_PRESSURE_PA:.0e} Pa (no soft segment holds a GPa: a parameter in the '
                'wrong unit, or beyond any material)')
    return None


def material_problem(material: 'Material') -> str | None:
    """Why a material law is no elastomer's in Pa (a GPa modulus, an overflow), or None."""
    modulus = float(material.shear_modulus)
    if not (math.isfinite(modulus) and abs(modulus) <= MAX_PRESSURE_PA):
        return (f'its initial shear modulus is {modulus:.3g} Pa, beyond {MAX_PRESSURE_PA:.0e} '
                'Pa: no elastomer is that stiff (moduli are in Pa)')
    top = min(MATERIAL_STRETCH, 1.0 + 0.999 * (material.max_stretch - 1.0))
    stretches = np.linspace(1.0, top, CURVE_SAMPLES)
    with np.errstate(all='ignore'):
        stress = np.asarray(material.energy_derivative(stretches), dtype=float)
    bad = ~np.isfinite(stress)
    if bad.any():
        return (f'its stress is {stress[int(np.argmax(bad))]} at stretch '
                f'{stretches[int(np.argmax(bad))]:.4g}: the law overflows there')
    return None


def segment_problem(segment: 'Segment') -> str | None:
    """The first unit, overflow or shape problem of a segment of any model, or None."""
    return (volume_problem(segment.max_volume, segment.length) or curve_problem(segment)
            or rising_problem(segment))


def rising_problem(segment: 'Segment') -> str | None:
    """
    Why no state of ``segment`` can be stable, or None.

    A segment sitting alone at a pressure is stable only where its pressure rises with its
    volume; one whose curve never rises (it falls or stays flat from its first row to its
    last) has no stable state, alone or beside others, and no assembly could start from rest.
    """
    from softseq_ros.segments.models import NEVER_RISES  # loaded with ``segment`` already

    if any(piece.direction > 0 for piece in segment.monotone_pieces()):
        return None
    return NEVER_RISES


def absolute_problem(pressures: NDArray[np.float64]) -> str | None:
    """Why readings declared absolute cannot be absolute pressures in Pa, or None."""
    lowest = float(np.min(pressures)) if pressures.size else MIN_ABSOLUTE_PA
    if lowest < MIN_ABSOLUTE_PA:
        return (f'an absolute pressure of {lowest:.6g} Pa is below {MIN_ABSOLUTE_PA:g} Pa, where '
                'a liquid boils (the ambient is about 101325 Pa absolute): '
                + KPA_HINT)
    return None


def ambient_problem(ambient_pa: float) -> str | None:
    """Why ``ambient_pa`` is no ambient pressure in Pa, or None."""
    lo, hi = AMBIENT_RANGE_PA
    if not lo <= ambient_pa <= hi:
        return (f'{ambient_pa:g} Pa is no ambient pressure (from {lo:g} to {hi:g} Pa; 101325 Pa '
                f'at sea level): {KPA_HINT}')
    return None
