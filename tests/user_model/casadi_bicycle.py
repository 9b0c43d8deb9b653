"""The paper's reduced dynamic bicycle (eq. 4, linear tyres) written as a CasADi expression,
as a vehicle engineer keeps a model for acados: x = [X, Y, psi, vy, r], u = [delta], and the
parameters as one vector p in the order of PARAMS."""
import casadi as ca

PARAMS = ("m", "Iz", "Lf", "Lr", "Caf", "Car", "vx")


def bicycle():
    """casadi.Function f(x, u, p) -> dx/dt of the linear-tyre reduced bicycle."""
    x, u, p = ca.SX.sym("x", 5), ca.SX.sym("u", 1), ca.SX.sym("p", len(PARAMS))
    m, Iz, Lf, Lr, Caf, Car, vx = ca.vertsplit(p)
    psi, vy, r, delta = x[2], x[3], x[4], u[0]
    Fyf = -Caf * ((vy + Lf * r) / vx - delta)
    Fyr = -Car * (vy - Lr * r) / vx
    dx = ca.vertcat(vx * ca.cos(psi) - vy * ca.sin(psi), vx * ca.sin(psi) + vy * ca.cos(psi),
                    r, (Fyf * ca.cos(delta) + Fyr) / m - vx * r,
                    (Lf * Fyf * ca.cos(delta) - Lr * Fyr) / Iz)
    return ca.Function("bicycle", [x, u, p], [dx], ["x", "u", "p"], ["dx"])
