"""The same single-track vehicle as vehicle.py, written as a CasADi expression (as for acados'
f_expl_expr): x = [X, Y, delta, v, psi, r, beta], u = [ddelta, a], p in the order of PARAMS."""
import casadi as ca

PARAMS = ("m", "Iz", "lf", "lr", "h", "mu", "csf", "csr")
STEER_MAX = 0.42   # [rad]
G = 9.81           # [m/s^2]


def single_track():
    """casadi.Function f(x, u, p) -> dx/dt."""
    x, u, p = ca.SX.sym("x", 7), ca.SX.sym("u", 2), ca.SX.sym("p", len(PARAMS))
    X, Y, delta, v, psi, r, beta = ca.vertsplit(x)
    ddelta, a = ca.vertsplit(u)
    m, Iz, lf, lr, h, mu, csf, csr = ca.vertsplit(p)
    steer = ca.fmin(ca.fmax(delta, -STEER_MAX), STEER_MAX)     # the clamp
    L = lf + lr
    kf = mu * csf * (G * lr - a * h) / L
    kr = mu * csr * (G * lf + a * h) / L
    dr = m / Iz * (lf * kf * (steer - beta - lf * r / v) - lr * kr * (lr * r / v - beta))
    dbeta = (kf * (steer - beta - lf * r / v) + kr * (lr * r / v - beta)) / v - r
    dx = ca.vertcat(v * ca.cos(psi + beta), v * ca.sin(psi + beta), ddelta, a, r, dr, dbeta)
    return ca.Function("single_track", [x, u, p], [dx], ["x", "u", "p"], ["dx"])
