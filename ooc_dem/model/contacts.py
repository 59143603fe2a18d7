"""The kernels' contact tables of a scenario: each contact section (model.schema.ContactPair,
materials already folded in by model.materials) as the CONTACT_PARAMS record of its
dimension's law (physics.d2.layout, physics.d3.layout)."""

from __future__ import annotations

from .schema import ContactPair, Scenario, clamps


def contact_params_3d(pair: ContactPair) -> tuple:
    """The 3D kernels' CONTACT_PARAMS tuple of a scenario contact section (physics.d3.layout):
    linear with the 2D keys, or Hertz-Mindlin with both surfaces of youngs_modulus and
    poisson_ratio, damping from restitution."""
    from ..physics.d3 import layout as L3

    if pair.law == "hertz":
        second = pair.youngs_modulus_2 > 0.0
        return L3.hertz_params(
            pair.youngs_modulus,
            pair.poisson_ratio,
            pair.restitution,
            mu=pair.friction,
            mur=pair.rolling_friction,
            zr=pair.rolling_damping,
            E2=pair.youngs_modulus_2 if second else pair.youngs_modulus,
            nu2=pair.poisson_ratio_2 if second else pair.poisson_ratio,
            no_tension=clamps(pair),
            kc=pair.cohesion,
        )
    return L3.linear_params(*_linear_args(pair), no_tension=clamps(pair), kc=pair.cohesion)


def _linear_args(pair: ContactPair) -> tuple[float, float, float, float, float, float, float]:
    """The linear law's parameters of a contact section, in the kernels' order."""
    return (
        pair.kn,
        pair.ks,
        pair.damping_n,
        pair.damping_t,
        pair.friction,
        pair.rolling_friction,
        pair.rolling_damping,
    )


def contact_params_2d(pair: ContactPair, thickness: float) -> tuple:
    """The 2D kernels' CONTACT_PARAMS tuple of a contact section (physics.d2.layout): the
    linear law, the discs' cohesion per unit of chord (the energy density times their
    thickness)."""
    from ..physics.d2 import layout as L2

    return L2.linear_params(*_linear_args(pair), no_tension=clamps(pair), kc=pair.cohesion * thickness)


def contact_table_3d(sc: Scenario):
    """CONTACT_PARAMS table [type_a, type_b] of a 3D scenario (soil-soil, soil-wall, soil-wheel)."""
    from ..physics.d3 import layout as L3

    c = sc.contact
    return L3.contact_table(
        {
            (L3.T_SOIL, L3.T_SOIL): contact_params_3d(c.soil_soil),
            (L3.T_WALL, L3.T_SOIL): contact_params_3d(c.soil_wall),
            (L3.T_WHEEL, L3.T_SOIL): contact_params_3d(c.soil_wheel),
        }
    )
