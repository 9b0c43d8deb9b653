"""Lateral tyre laws of the dynamic bicycle, one axle at a time: the force Fy [N] from the slip
angle alpha [rad], opposing the slip (Fy = -C_alpha * alpha at small slip for every law).

Each law reads its axle's parameters from p with the suffix "f" or "r":
- linear:  Ca  [N/rad] cornering stiffness (the paper's tyre).
- pacejka: B [1/rad], C, D [N], E of the magic formula (Pacejka, Tyre and Vehicle
  Dynamics, 3rd ed., 2012, ch. 4) without shifts; its slope at zero slip is B*C*D.
- fiala:   Ca [N/rad], mu, Fz [N] of the brush model with a parabolic pressure
  distribution and one friction coefficient (Fiala 1954; Pacejka 2012, ch. 3, with
  equal static and sliding friction); its slope at zero slip is Ca, and it saturates at mu*Fz
  beyond the sliding angle atan(3 mu Fz / Ca)."""
import jax.numpy as jnp

TYRES = ("linear", "pacejka", "fiala")
DEFAULT_TYRE = "linear"


def linear(alpha, p, axle):
    return -p["Ca" + axle] * alpha


def pacejka(alpha, p, axle):
    B, C, D, E = (p[k + axle] for k in "BCDE")
    Ba = B * alpha
    return -D * jnp.sin(C * jnp.arctan(Ba - E * (Ba - jnp.arctan(Ba))))


def fiala(alpha, p, axle):
    Ca, grip = p["Ca" + axle], p["mu"] * p["Fz" + axle]
    z = jnp.tan(alpha)
    # Below the sliding angle the contact patch still adheres in part (cubic in tan alpha);
    # beyond it the whole patch slides and the force is the friction limit.
    adhesion = -Ca * z + Ca**2 / (3 * grip) * jnp.abs(z) * z - Ca**3 / (27 * grip**2) * z**3
    sliding = jnp.abs(z) >= 3 * grip / Ca
    return jnp.where(sliding, -grip * jnp.sign(alpha), adhesion)


LAWS = {"linear": linear, "pacejka": pacejka, "fiala": fiala}


def tyre_name(name: str | None) -> str:
    """The tyre model's name (None: the default); raises KeyError naming the known ones."""
    name = name or DEFAULT_TYRE
    if name not in LAWS:
        raise KeyError(f"unknown tyre {name!r}; known: {', '.join(TYRES)}")
    return name


def tyre_law(name: str | None):
    """The force law Fy(alpha, p, axle) of a tyre model by name."""
    return LAWS[tyre_name(name)]
