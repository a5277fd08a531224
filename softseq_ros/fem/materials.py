"""
Hyperelastic laws for the FEM, built from the material block that scenes and designs share.

The names and units are those of :mod:`softseq_ros.segments.materials` (``law`` plus parameters
in Pa), so a design's material can be checked against the membrane models. Each law gives felupe
the distortional (isochoric) part of the strain energy only; the volumetric part is the
nearly-incompressible solid's (``bulk`` modulus on a cell-wise constant dilatation).

Conversions: Abaqus' Arruda-Boyce ``mu`` is felupe's ``C1`` (same five-term series, ``limit`` =
lambda_m); an Ogden term ``mu_i / alpha_i (sum l^alpha_i - 3)`` is felupe's
``2 m_i / alpha_i^2 (...)`` with ``m_i = mu_i alpha_i / 2``; Gent is written here.
"""

from typing import Any

import felupe as fem
import tensortrax.math as tm


def _gent(C: Any, mu: float, jm: float) -> Any:  # noqa: N803 (C is the tensor's usual name)
    """Isochoric Gent energy, -mu Jm / 2 ln(1 - (I1 - 3) / Jm), of a right Cauchy-Green C."""
    i1 = tm.linalg.det(C) ** (-1 / 3) * tm.trace(C)
    return -mu * jm / 2 * tm.log(1 - (i1 - 3) / jm)


def initial_shear_modulus(law: str, params: dict[str, Any]) -> float:
    """Initial shear modulus [Pa] of a law, to scale the bulk modulus and the tolerances."""
    from softseq_ros.segments.materials import make_material

    return float(make_material(law, params).shear_modulus)


def make_umat(law: str, params: dict[str, Any]) -> Any:
    """The felupe material (distortional part) of one of the scene laws."""
    if law == 'neo_hookean':
        return fem.NeoHooke(mu=params['shear_modulus_pa'])
    if law == 'mooney_rivlin':
        return fem.Hyperelastic(fem.mooney_rivlin, C10=params['c1_pa'], C01=params['c2_pa'])
    if law == 'yeoh':
        return fem.Hyperelastic(fem.yeoh, C10=params['c1_pa'], C20=params['c2_pa'],
                                C30=params.get('c3_pa', 0.0))
    if law == 'arruda_boyce':
        return fem.Hyperelastic(fem.arruda_boyce, C1=params['shear_modulus_pa'],
                                limit=params['lambda_m'])
    if law == 'gent':
        return fem.Hyperelastic(_gent, mu=params['shear_modulus_pa'], jm=params['jm'])
    if law == 'ogden':
        moduli = [m * a / 2 for m, a in zip(params['mu_pa'], params['alpha'])]
        return fem.Hyperelastic(fem.ogden, mu=moduli, alpha=list(params['alpha']))
    raise ValueError(f'unknown material law {law!r}')
