"""Two CommonRoad vehicle models with wheel dynamics, in JAX: the single-track drift model
(STD, 9 states) and the multi-body model (MB, 29 states), with the BMW 320i parameters
(vehicle ID 2) and its Pacejka tyre. Ported as written in the CommonRoad vehicle models
(Althoff, Koschi and Manzinger, "CommonRoad: Vehicle Models", TU Munich, 2020;
github.com/CommonRoad/commonroad-vehicle-models, Python package `vehiclemodels` 3.0.2:
vehicle_dynamics_std.py, vehicle_dynamics_mb.py, utils/tire_model.py, the constraints in
utils/, parameters/parameters_vehicle2.yaml and parameters_tire.yaml), branches as
selections. Right-hand sides f(t, x, u, p) with u = (steering angle velocity [rad/s],
longitudinal acceleration [m/s^2]) and p = `BMW_320I` (or a copy with other values).

The wheel speeds make both stiff: a wheel's slip stiffness over its inertia and the car's
speed puts fast-decaying modes (the faster, the slower the car) beside the body's slow ones
(their values: docs/studies/implicit-speed-2026-11-28.md)."""
import jax.numpy as jnp

from stepzoo.dynamics.single_track import G, _kinematic, constrained_inputs

# parameters_tire.yaml (the same tyre for every CommonRoad vehicle)
TIRE = dict(p_cx1=1.6411, p_dx1=1.1739, p_dx3=0.0, p_ex1=0.46403, p_kx1=22.303,
            p_hx1=0.0012297, p_vx1=-8.8098e-06, r_bx1=13.276, r_bx2=-13.778, r_cx1=1.2568,
            r_ex1=0.65225, r_hx1=0.0050722, p_cy1=1.3507, p_dy1=1.0489, p_dy3=-2.8821,
            p_ey1=-0.0074722, p_ky1=-21.92, p_hy1=0.0026747, p_hy3=0.031415, p_vy1=0.037318,
            p_vy3=-0.32931, r_by1=7.1433, r_by2=9.1916, r_by3=-0.027856, r_cy1=1.0719,
            r_ey1=-0.27572, r_hy1=5.7448e-06, r_vy1=-0.027825, r_vy3=-0.27568, r_vy4=12.12,
            r_vy5=1.9, r_vy6=-10.704)

# parameters_vehicle2.yaml: BMW 320i. Masses [kg], lengths [m], inertias [kg m^2],
# stiffnesses [N/m], [N m/rad], dampings [N s/m], K_lt [m/N].
# The steering and acceleration limits under single_track's names (constrained_inputs).
BMW_320I = dict(
    delta_min=-1.066, delta_max=1.066, ddelta_min=-0.4, ddelta_max=0.4,
    a_max=11.5, v_max=50.8, v_min=-13.9, v_switch=7.319,
    m=1093.2952334674046, m_s=965.7108098804363, m_uf=63.7921826056784,
    m_ur=63.7921826056784, a=1.1561957064, b=1.4227170936, I_Phi_s=207.26524557936952,
    I_y_s=1565.8178787125541, I_z=1791.5995300122856, I_xz_s=0.0, K_sf=24453.137879749014,
    K_sdf=1786.2441002440723, K_sr=19635.504745231297, K_sdr=1649.0833034887382, T_f=1.38684,
    T_r=1.36398, K_ras=175186.65943700788, K_tsf=-6914.881688272133,
    K_tsr=-2643.6009520155308, K_rad=10215.732056044453, K_zt=158294.1398119115,
    h_cg=0.5748689544000001, h_raf=0.0, h_rar=0.0, h_s=0.61373004, I_uf=30.673279563178017,
    I_ur=29.670408143156248, I_y_w=1.7, K_lt=1.6430724599974725e-05, R_w=0.344, T_sb=0.66,
    T_se=0.0, D_f=-0.39370078740157477, D_r=-0.905511811023622, E_f=0.0, E_r=0.0, tire=TIRE)


class _Params:
    """Attribute access to a parameter dict (nested dicts too), so that the equations read
    as published."""

    def __init__(self, d):
        for k, v in d.items():
            setattr(self, k, _Params(v) if isinstance(v, dict) else v)


def _sign(x):
    return jnp.sign(x)


def _magic(b, c, e, x):
    """c atan(b x - e (b x - atan(b x))): the magic formula's inner term."""
    return c * jnp.arctan(b * x - e * (b * x - jnp.arctan(b * x)))


def formula_longitudinal(kappa, gamma, f_z, p):
    """utils/tire_model.py: pure-slip longitudinal force (S_vx inside the sine, as there)."""
    kappa = -kappa
    kappa_x = kappa + p.p_hx1
    d_x = p.p_dx1 * (1 - p.p_dx3 * gamma ** 2) * f_z
    b_x = f_z * p.p_kx1 / (p.p_cx1 * d_x)
    return d_x * jnp.sin(_magic(b_x, p.p_cx1, p.p_ex1, kappa_x) + f_z * p.p_vx1)


def formula_lateral(alpha, gamma, f_z, p):
    """utils/tire_model.py: pure-slip lateral force and friction coefficient mu_y."""
    s_hy = _sign(gamma) * (p.p_hy1 + p.p_hy3 * jnp.abs(gamma))
    s_vy = _sign(gamma) * f_z * (p.p_vy1 + p.p_vy3 * jnp.abs(gamma))
    mu_y = p.p_dy1 * (1 - p.p_dy3 * gamma ** 2)
    d_y = mu_y * f_z
    b_y = f_z * p.p_ky1 / (p.p_cy1 * d_y)
    return d_y * jnp.sin(_magic(b_y, p.p_cy1, p.p_ey1, alpha + s_hy)) + s_vy, mu_y


def formula_longitudinal_comb(kappa, alpha, f0_x, p):
    """utils/tire_model.py: longitudinal force under combined slip."""
    b = p.r_bx1 * jnp.cos(jnp.arctan(p.r_bx2 * kappa))
    d = f0_x / jnp.cos(_magic(b, p.r_cx1, p.r_ex1, p.r_hx1))
    return d * jnp.cos(_magic(b, p.r_cx1, p.r_ex1, alpha + p.r_hx1))


def formula_lateral_comb(kappa, alpha, gamma, mu_y, f_z, f0_y, p):
    """utils/tire_model.py: lateral force under combined slip."""
    b = p.r_by1 * jnp.cos(jnp.arctan(p.r_by2 * (alpha - p.r_by3)))
    d = f0_y / jnp.cos(_magic(b, p.r_cy1, p.r_ey1, p.r_hy1))
    d_v = mu_y * f_z * (p.r_vy1 + p.r_vy3 * gamma) * jnp.cos(jnp.arctan(p.r_vy4 * alpha))
    return (d * jnp.cos(_magic(b, p.r_cy1, p.r_ey1, kappa + p.r_hy1))
            + d_v * jnp.sin(p.r_vy5 * jnp.arctan(p.r_vy6 * kappa)))


def _inputs_and_kinematic(x, u, p):
    """(constrained u, the kinematic single track's rates about the centre of gravity at
    x[:7] (single_track's, with p's a and b as Lf and Lr): x, y, delta, v, psi, dd psi,
    d beta), as both published models blend or switch to them at low speed."""
    u = constrained_inputs(x[2], x[3], u[0], u[1], p)
    return u, _kinematic(x[:7], *u, dict(p, Lf=p["a"], Lr=p["b"]))


def _torques(m, r_w, accel):
    """(brake, engine) torque [N m] of the acceleration input."""
    return jnp.where(accel > 0, 0.0, m * r_w * accel), jnp.where(accel > 0, m * r_w * accel, 0.0)


def _tyres(kappa, alpha, gamma, f_z, tire):
    """(f_x, f_y) [N] of wheels given as arrays (one entry a wheel) of their longitudinal
    slips, slip angles [rad], camber angles [rad] and vertical forces [N]: pure slip, then
    combined. The wheels go through the formulas together, so that a model's compiled
    program holds them once and not once a wheel."""
    f0_x = formula_longitudinal(kappa, gamma, f_z, tire)
    f0_y, mu_y = formula_lateral(alpha, gamma, f_z, tire)
    return (formula_longitudinal_comb(kappa, alpha, f0_x, tire),
            formula_lateral_comb(kappa, alpha, gamma, mu_y, f_z, f0_y, tire))


def std_rhs(t, x, u, p):
    """Single-track drift model, vehicle_dynamics_std.py. x: position (x, y) [m], steering
    angle [rad], speed at the centre of gravity [m/s], yaw [rad], yaw rate [rad/s], slip
    angle at the centre [rad], front and rear wheel speeds [rad/s]."""
    u, f_ks = _inputs_and_kinematic(x, u, p)
    p = _Params(p)
    lf, lr, m, inertia = p.a, p.b, p.m, p.I_z
    v_s, v_b = 0.2, 0.05
    v_min = v_s / 2
    moving = x[3] > v_min
    vc = jnp.where(moving, x[3], 1.0)      # no division by a speed the selection drops
    alpha_f = jnp.where(moving, jnp.arctan((vc * jnp.sin(x[6]) + x[5] * lf)
                                           / (vc * jnp.cos(x[6]))) - x[2], 0.0)
    alpha_r = jnp.where(moving, jnp.arctan((vc * jnp.sin(x[6]) - x[5] * lr)
                                           / (vc * jnp.cos(x[6]))), 0.0)
    f_zf = m * (-u[1] * p.h_s + G * lr) / (lr + lf)
    f_zr = m * (u[1] * p.h_s + G * lf) / (lr + lf)
    u_wf = jnp.maximum(0.0, x[3] * jnp.cos(x[6]) * jnp.cos(x[2])
                       + (x[3] * jnp.sin(x[6]) + p.a * x[5]) * jnp.sin(x[2]))
    u_wr = jnp.maximum(0.0, x[3] * jnp.cos(x[6]))
    s_f = 1 - p.R_w * x[7] / jnp.maximum(u_wf, v_min)
    s_r = 1 - p.R_w * x[8] / jnp.maximum(u_wr, v_min)
    (f_xf, f_xr), (f_yf, f_yr) = _tyres(jnp.stack([s_f, s_r]), jnp.stack([alpha_f, alpha_r]),
                                        0.0, jnp.stack([f_zf, f_zr]), p.tire)
    t_b, t_e = _torques(m, p.R_w, u[1])
    d_v = 1 / m * (-f_yf * jnp.sin(x[2] - x[6]) + f_yr * jnp.sin(x[6])
                   + f_xr * jnp.cos(x[6]) + f_xf * jnp.cos(x[2] - x[6]))
    dd_psi = 1 / inertia * (f_yf * jnp.cos(x[2]) * lf - f_yr * lr
                            + f_xf * jnp.sin(x[2]) * lf)
    d_beta = jnp.where(moving, -x[5] + 1 / (m * vc) * (
        f_yf * jnp.cos(x[2] - x[6]) + f_yr * jnp.cos(x[6]) - f_xr * jnp.sin(x[6])
        + f_xf * jnp.sin(x[2] - x[6])), 0.0)
    d_omega_f = jnp.where(x[7] >= 0, 1 / p.I_y_w * (-p.R_w * f_xf + p.T_sb * t_b
                                                    + p.T_se * t_e), 0.0)
    d_omega_r = jnp.where(x[8] >= 0, 1 / p.I_y_w * (-p.R_w * f_xr + (1 - p.T_sb) * t_b
                                                    + (1 - p.T_se) * t_e), 0.0)
    # The published function clips the wheel speeds to >= 0 in place before the kinematic
    # blend reads them.
    omega_f, omega_r = jnp.maximum(0.0, x[7]), jnp.maximum(0.0, x[8])
    d_omega_f_ks = (1 / 0.02) * (u_wf / p.R_w - omega_f)
    d_omega_r_ks = (1 / 0.02) * (u_wr / p.R_w - omega_r)
    w_std = 0.5 * (jnp.tanh((x[3] - v_s) / v_b) + 1)
    w_ks = 1 - w_std
    return jnp.stack([x[3] * jnp.cos(x[6] + x[4]), x[3] * jnp.sin(x[6] + x[4]), u[0],
                      w_std * d_v + w_ks * f_ks[3], w_std * x[5] + w_ks * f_ks[4],
                      w_std * dd_psi + w_ks * f_ks[5], w_std * d_beta + w_ks * f_ks[6],
                      w_std * d_omega_f + w_ks * d_omega_f_ks,
                      w_std * d_omega_r + w_ks * d_omega_r_ks])


def std_state(x, y, delta, v, psi, psi_dot, beta, p=BMW_320I):
    """init_std.py: the 9 states with the wheels rolling at the car's speed."""
    return jnp.stack([x, y, delta, v, psi, psi_dot, beta,
                      v * jnp.cos(beta) * jnp.cos(delta) / p["R_w"],
                      v * jnp.cos(beta) / p["R_w"]])


def mb_rhs(t, x, u, p):
    """Multi-body model, vehicle_dynamics_mb.py: 29 states, the sprung mass (position,
    velocities, yaw, roll and pitch with their rates, height), the front and rear unsprung
    masses (roll, lateral velocity, height, with rates), the four wheel speeds [rad/s] and the
    compliant joints' lateral deflections delta_y_f, delta_y_r [m]; x[2] is the steering
    angle, x[3] the longitudinal velocity [m/s]."""
    u, f_ks = _inputs_and_kinematic(x, u, p)
    p = _Params(p)
    tire = p.tire
    slow = jnp.abs(x[3]) < 0.1
    vx = jnp.where(slow, 1.0, x[3])        # no division by a speed the selection drops
    beta = jnp.where(slow, 0.0, jnp.arctan(x[10] / vx))
    vel = jnp.sqrt(x[3] ** 2 + x[10] ** 2)
    cos, sin = jnp.cos, jnp.sin
    # vertical tyre forces
    f_z_lf = (x[16] + p.R_w * (cos(x[13]) - 1) - 0.5 * p.T_f * sin(x[13])) * p.K_zt
    f_z_rf = (x[16] + p.R_w * (cos(x[13]) - 1) + 0.5 * p.T_f * sin(x[13])) * p.K_zt
    f_z_lr = (x[21] + p.R_w * (cos(x[18]) - 1) - 0.5 * p.T_r * sin(x[18])) * p.K_zt
    f_z_rr = (x[21] + p.R_w * (cos(x[18]) - 1) + 0.5 * p.T_r * sin(x[18])) * p.K_zt
    # tyre speeds, negative wheel spin forbidden
    u_w_lf = jnp.maximum((x[3] + 0.5 * p.T_f * x[5]) * cos(x[2])
                         + (x[10] + p.a * x[5]) * sin(x[2]), 0.0)
    u_w_rf = jnp.maximum((x[3] - 0.5 * p.T_f * x[5]) * cos(x[2])
                         + (x[10] + p.a * x[5]) * sin(x[2]), 0.0)
    u_w_lr = jnp.maximum(x[3] + 0.5 * p.T_r * x[5], 0.0)
    u_w_rr = jnp.maximum(x[3] - 0.5 * p.T_r * x[5], 0.0)
    # longitudinal slips and slip angles (zero below 0.1 m/s)
    slip = lambda omega, uw: jnp.where(slow, 0.0, 1 - p.R_w * omega / jnp.where(slow, 1.0, uw))
    s_lf, s_rf = slip(x[23], u_w_lf), slip(x[24], u_w_rf)
    s_lr, s_rr = slip(x[25], u_w_lr), slip(x[26], u_w_rr)
    angle = lambda num, den: jnp.where(slow, 0.0, jnp.arctan(num / jnp.where(slow, 1.0, den)))
    front = x[10] + p.a * x[5] - x[14] * (p.R_w - x[16])
    rear = x[10] - p.b * x[5] - x[19] * (p.R_w - x[21])
    alpha_lf = angle(front, x[3] + 0.5 * p.T_f * x[5]) - jnp.where(slow, 0.0, x[2])
    alpha_rf = angle(front, x[3] - 0.5 * p.T_f * x[5]) - jnp.where(slow, 0.0, x[2])
    alpha_lr = angle(rear, x[3] + 0.5 * p.T_r * x[5])
    alpha_rr = angle(rear, x[3] - 0.5 * p.T_r * x[5])
    # suspension travel and its rate
    z_slf = ((p.h_s - p.R_w + x[16] - x[11]) / cos(x[6]) - p.h_s + p.R_w + p.a * x[8]
             + 0.5 * (x[6] - x[13]) * p.T_f)
    z_srf = ((p.h_s - p.R_w + x[16] - x[11]) / cos(x[6]) - p.h_s + p.R_w + p.a * x[8]
             - 0.5 * (x[6] - x[13]) * p.T_f)
    z_slr = ((p.h_s - p.R_w + x[21] - x[11]) / cos(x[6]) - p.h_s + p.R_w - p.b * x[8]
             + 0.5 * (x[6] - x[18]) * p.T_r)
    z_srr = ((p.h_s - p.R_w + x[21] - x[11]) / cos(x[6]) - p.h_s + p.R_w - p.b * x[8]
             - 0.5 * (x[6] - x[18]) * p.T_r)
    dz_slf = x[17] - x[12] + p.a * x[9] + 0.5 * (x[7] - x[14]) * p.T_f
    dz_srf = x[17] - x[12] + p.a * x[9] - 0.5 * (x[7] - x[14]) * p.T_f
    dz_slr = x[22] - x[12] - p.b * x[9] + 0.5 * (x[7] - x[19]) * p.T_r
    dz_srr = x[22] - x[12] - p.b * x[9] - 0.5 * (x[7] - x[19]) * p.T_r
    # camber angles
    gamma_lf = x[6] + p.D_f * z_slf + p.E_f * z_slf ** 2
    gamma_rf = x[6] - p.D_f * z_srf - p.E_f * z_srf ** 2
    gamma_lr = x[6] + p.D_r * z_slr + p.E_r * z_slr ** 2
    gamma_rr = x[6] - p.D_r * z_srr - p.E_r * z_srr ** 2
    # tyre forces: pure slip, then combined, the four wheels as one array each
    f_x, f_y = _tyres(jnp.stack([s_lf, s_rf, s_lr, s_rr]),
                      jnp.stack([alpha_lf, alpha_rf, alpha_lr, alpha_rr]),
                      jnp.stack([gamma_lf, gamma_rf, gamma_lr, gamma_rr]),
                      jnp.stack([f_z_lf, f_z_rf, f_z_lr, f_z_rr]), tire)
    f_x_lf, f_x_rf, f_x_lr, f_x_rr = f_x
    f_y_lf, f_y_rf, f_y_lr, f_y_rr = f_y
    # compliant joints
    delta_z_f = p.h_s - p.R_w + x[16] - x[11]
    delta_z_r = p.h_s - p.R_w + x[21] - x[11]
    delta_phi_f, delta_phi_r = x[6] - x[13], x[6] - x[18]
    dot_delta_phi_f, dot_delta_phi_r = x[7] - x[14], x[7] - x[19]
    dot_delta_z_f, dot_delta_z_r = x[17] - x[12], x[22] - x[12]
    dot_delta_y_f = x[10] + p.a * x[5] - x[15]
    dot_delta_y_r = x[10] - p.b * x[5] - x[20]
    delta_f = (delta_z_f * sin(x[6]) - x[27] * cos(x[6])
               - (p.h_raf - p.R_w) * sin(delta_phi_f))
    delta_r = (delta_z_r * sin(x[6]) - x[28] * cos(x[6])
               - (p.h_rar - p.R_w) * sin(delta_phi_r))
    dot_delta_f = ((delta_z_f * cos(x[6]) + x[27] * sin(x[6])) * x[7]
                   + dot_delta_z_f * sin(x[6]) - dot_delta_y_f * cos(x[6])
                   - (p.h_raf - p.R_w) * cos(delta_phi_f) * dot_delta_phi_f)
    dot_delta_r = ((delta_z_r * cos(x[6]) + x[28] * sin(x[6])) * x[7]
                   + dot_delta_z_r * sin(x[6]) - dot_delta_y_r * cos(x[6])
                   - (p.h_rar - p.R_w) * cos(delta_phi_r) * dot_delta_phi_r)
    f_raf = delta_f * p.K_ras + dot_delta_f * p.K_rad
    f_rar = delta_r * p.K_ras + dot_delta_r * p.K_rad
    # suspension forces
    f_slf = (p.m_s * G * p.b / (2 * (p.a + p.b)) - z_slf * p.K_sf - dz_slf * p.K_sdf
             + (x[6] - x[13]) * p.K_tsf / p.T_f)
    f_srf = (p.m_s * G * p.b / (2 * (p.a + p.b)) - z_srf * p.K_sf - dz_srf * p.K_sdf
             - (x[6] - x[13]) * p.K_tsf / p.T_f)
    f_slr = (p.m_s * G * p.a / (2 * (p.a + p.b)) - z_slr * p.K_sr - dz_slr * p.K_sdr
             + (x[6] - x[18]) * p.K_tsr / p.T_r)
    f_srr = (p.m_s * G * p.a / (2 * (p.a + p.b)) - z_srr * p.K_sr - dz_srr * p.K_sdr
             - (x[6] - x[18]) * p.K_tsr / p.T_r)
    # sums on the sprung mass
    sum_x = (f_x_lr + f_x_rr + (f_x_lf + f_x_rf) * cos(x[2])
             - (f_y_lf + f_y_rf) * sin(x[2]))
    sum_n = ((f_y_lf + f_y_rf) * p.a * cos(x[2]) + (f_x_lf + f_x_rf) * p.a * sin(x[2])
             + (f_y_rf - f_y_lf) * 0.5 * p.T_f * sin(x[2])
             + (f_x_lf - f_x_rf) * 0.5 * p.T_f * cos(x[2])
             + (f_x_lr - f_x_rr) * 0.5 * p.T_r - (f_y_lr + f_y_rr) * p.b)
    sum_y_s = (f_raf + f_rar) * cos(x[6]) + (f_slf + f_slr + f_srf + f_srr) * sin(x[6])
    sum_l = (0.5 * f_slf * p.T_f + 0.5 * f_slr * p.T_r - 0.5 * f_srf * p.T_f
             - 0.5 * f_srr * p.T_r
             - f_raf / cos(x[6]) * (p.h_s - x[11] - p.R_w + x[16]
                                    - (p.h_raf - p.R_w) * cos(x[13]))
             - f_rar / cos(x[6]) * (p.h_s - x[11] - p.R_w + x[21]
                                    - (p.h_rar - p.R_w) * cos(x[18])))
    sum_z_s = (f_slf + f_slr + f_srf + f_srr) * cos(x[6]) - (f_raf + f_rar) * sin(x[6])
    sum_m_s = (p.a * (f_slf + f_srf) - p.b * (f_slr + f_srr)
               + ((f_x_lf + f_x_rf) * cos(x[2]) - (f_y_lf + f_y_rf) * sin(x[2])
                  + f_x_lr + f_x_rr) * (p.h_s - x[11]))
    # sums on the unsprung masses
    sum_l_uf = (0.5 * f_srf * p.T_f - 0.5 * f_slf * p.T_f - f_raf * (p.h_raf - p.R_w)
                + f_z_lf * (p.R_w * sin(x[13]) + 0.5 * p.T_f * cos(x[13]) - p.K_lt * f_y_lf)
                - f_z_rf * (-p.R_w * sin(x[13]) + 0.5 * p.T_f * cos(x[13]) + p.K_lt * f_y_rf)
                - ((f_y_lf + f_y_rf) * cos(x[2]) + (f_x_lf + f_x_rf) * sin(x[2]))
                * (p.R_w - x[16]))
    sum_l_ur = (0.5 * f_srr * p.T_r - 0.5 * f_slr * p.T_r - f_rar * (p.h_rar - p.R_w)
                + f_z_lr * (p.R_w * sin(x[18]) + 0.5 * p.T_r * cos(x[18]) - p.K_lt * f_y_lr)
                - f_z_rr * (-p.R_w * sin(x[18]) + 0.5 * p.T_r * cos(x[18]) + p.K_lt * f_y_rr)
                - (f_y_lr + f_y_rr) * (p.R_w - x[21]))
    sum_z_uf = f_z_lf + f_z_rf + f_raf * sin(x[6]) - (f_slf + f_srf) * cos(x[6])
    sum_z_ur = f_z_lr + f_z_rr + f_rar * sin(x[6]) - (f_slr + f_srr) * cos(x[6])
    sum_y_uf = ((f_y_lf + f_y_rf) * cos(x[2]) + (f_x_lf + f_x_rf) * sin(x[2])
                - f_raf * cos(x[6]) - (f_slf + f_srf) * sin(x[6]))
    sum_y_ur = (f_y_lr + f_y_rr) - f_rar * cos(x[6]) - (f_slr + f_srr) * sin(x[6])
    # the single-track part: kinematic below 0.1 m/s
    dynamic = [cos(beta + x[4]) * vel, sin(beta + x[4]) * vel, u[0],
               1 / p.m * sum_x + x[5] * x[10], x[5],
               1 / (p.I_z - p.I_xz_s ** 2 / p.I_Phi_s) * (sum_n + p.I_xz_s / p.I_Phi_s * sum_l)]
    f = [jnp.where(slow, f_ks[i], d) for i, d in enumerate(dynamic)]
    f += [x[7], 1 / (p.I_Phi_s - p.I_xz_s ** 2 / p.I_z) * (p.I_xz_s / p.I_z * sum_n + sum_l),
          x[9], 1 / p.I_y_s * sum_m_s, 1 / p.m_s * sum_y_s - x[5] * x[3], x[12],
          G - 1 / p.m_s * sum_z_s,
          x[14], 1 / p.I_uf * sum_l_uf, 1 / p.m_uf * sum_y_uf - x[5] * x[3], x[17],
          G - 1 / p.m_uf * sum_z_uf,
          x[19], 1 / p.I_ur * sum_l_ur, 1 / p.m_ur * sum_y_ur - x[5] * x[3], x[22],
          G - 1 / p.m_ur * sum_z_ur]
    t_b, t_e = _torques(p.m, p.R_w, u[1])
    torques = (0.5 * p.T_sb * t_b + 0.5 * p.T_se * t_e,) * 2 + \
        (0.5 * (1 - p.T_sb) * t_b + 0.5 * (1 - p.T_se) * t_e,) * 2
    for i, (fx, torque) in enumerate(zip(f_x, torques)):
        # negative wheel spin forbidden: no acceleration of a wheel turning backwards
        f.append(jnp.where(x[23 + i] < 0, 0.0, 1 / p.I_y_w * (-p.R_w * fx + torque)))
    f += [dot_delta_y_f, dot_delta_y_r]
    return jnp.stack(f)


def mb_state(x, y, delta, v, psi, psi_dot, beta, p=BMW_320I):
    """init_mb.py: the 29 states at rest on the suspension, wheels rolling at the car's
    speed."""
    f0_z_f = p["m_s"] * G * p["b"] / (p["a"] + p["b"]) + p["m_uf"] * G
    f0_z_r = p["m_s"] * G * p["a"] / (p["a"] + p["b"]) + p["m_ur"] * G
    vx, vy = jnp.cos(beta) * v, jnp.sin(beta) * v
    zero = 0.0 * v
    return jnp.stack([x, y, delta, vx, psi, psi_dot, zero, zero, zero, zero, vy, zero, zero,
                      zero, zero, vy + p["a"] * psi_dot, zero + f0_z_f / (2 * p["K_zt"]), zero,
                      zero, zero, vy - p["b"] * psi_dot, zero + f0_z_r / (2 * p["K_zt"]), zero,
                      *(vx / p["R_w"] for _ in range(4)), zero, zero])
