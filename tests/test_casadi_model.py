"""CasADi models in: the JAX translation of a casadi.Function (dynamics.casadi_model) equals
CasADi's own evaluation and Jacobian, a sweep of the paper's bicycle written in CasADi
([model] casadi) measures the limits of the JAX bicycle, and a model that cannot be had is
one line and exit status 2."""
import json
import sys
from pathlib import Path

import casadi as ca
import jax
import numpy as np
import pandas as pd
import pytest

from stepzoo import dynamics
from stepzoo.cli import main as stepzoo
from stepzoo.bench.sweep.engine import run_sweep
from stepzoo.bench.sweep.config import load
from stepzoo.dynamics.casadi_model import rhs, to_jax
from helpers import TINY_SWEEP, two_state_config

USER = Path(__file__).resolve().parent / "user_model"
sys.path.insert(0, str(USER))
from casadi_bicycle import PARAMS, bicycle  # noqa: E402

sys.path.remove(str(USER))


def every_operation():
    """A function of x (3), u (1), p (2), t using the scalar operations a model may use,
    constants of every size among them."""
    x, u, p, t = ca.SX.sym("x", 3), ca.SX.sym("u", 1), ca.SX.sym("p", 2), ca.SX.sym("t")
    a, b, c = x[0], x[1], x[2]
    out = ca.vertcat(
        ca.sin(a) * ca.cos(b) + ca.tan(0.3 * c) + ca.exp(-a ** 2) + ca.log(1 + b ** 2),
        ca.sqrt(a ** 2 + 1) * p[0] + a ** p[1] / (1 + ca.fabs(b)) + ca.atan2(b, a)
        + ca.hypot(a, c) + 1.234567890123456e-7 * c + 1e-20 + ca.fmod(b, 0.7),
        ca.fmin(a, 0.4) + ca.fmax(b, -0.2) + ca.if_else(c > 0.1, a * b, -c) + ca.tanh(u)
        + ca.sinh(0.5 * a) + ca.cosh(0.2 * b) + ca.asinh(c) + ca.atan(b) + ca.erf(a)
        + ca.log1p(b ** 2) + ca.expm1(0.1 * c) + ca.sign(b) * ca.floor(3 * c) + t * a ** 2
        + ca.asin(0.5 * ca.tanh(c)) + ca.acos(0.3 * ca.tanh(b)) + ca.atanh(0.5 * ca.tanh(a))
        + ca.acosh(2 + b ** 2) + ca.power(u, 3) + ca.logic_and(a > 0, b < 1)
        + ca.logic_or(a >= 2, b <= -1) + ca.logic_not(c == 0.5) + (a != b),
        ca.remainder(a, 0.3) + ca.copysign(b, -1.0) + ca.ceil(2 * c) + 1 / (1 + a ** 2)
        + ca.erfinv(0.5 * ca.tanh(a)) + 2 * b - c + b ** 2.5)
    return ca.Function("every", [x, u, p, t], [out], ["x", "u", "p", "t"], ["dx"])


@pytest.mark.parametrize("make", [every_operation, bicycle])
def test_converted_f_and_its_jacobian_equal_casadis_own_at_random_points(make):
    fn = make()
    sym = [ca.SX.sym(fn.name_in(k), fn.numel_in(k)) for k in range(fn.n_in())]
    jac = ca.Function("jacobian_xu", sym, [ca.jacobian(fn(*sym), ca.vertcat(*sym[:2]))])
    f = to_jax(fn)
    jf = jax.jit(jax.jacfwd(lambda x, u, *rest: f(x, u, *rest)[0], argnums=(0, 1)))
    rng = np.random.default_rng(7)
    for _ in range(20):
        args = [rng.uniform(0.3, 1.5, fn.numel_in(k)) for k in range(fn.n_in())]
        want_f = np.asarray(fn(*args)).ravel()
        want_j = np.asarray(jac(*args))
        got_f = np.asarray(f(*args)[0])
        got_j = np.hstack([np.asarray(j) for j in jf(*args)])
        np.testing.assert_allclose(got_f, want_f, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got_j, want_j, rtol=1e-12, atol=1e-12)


def test_an_mx_function_is_expanded_and_equals_the_jax_bicycle():
    x, u, p = ca.MX.sym("x", 5), ca.MX.sym("u", 1), ca.MX.sym("p", len(PARAMS))
    mx = ca.Function("bicycle_mx", [x, u, p], [bicycle()(x, u, p)])
    m = dynamics.model("dynamic5")
    params = m.params(None, 12.0)
    f = rhs(mx, 5, 1, PARAMS)
    state, steer = np.array([1.0, -2.0, 0.4, 0.3, -0.1]), np.array([0.2])
    np.testing.assert_allclose(f(0.0, state, steer, params),
                               m.rhs(0.0, state, steer, params), rtol=1e-13, atol=1e-13)


def casadi_config(folder: Path, model: str) -> Path:
    """TINY_SWEEP with the bicycle from CasADi (`model`: its model.casadi), the default
    vehicle's parameters in [params], vx an entry of p."""
    p = dynamics.model("dynamic5").params(None, 15.0)
    params = "\n".join(f"{k} = {p[k]!r}" for k in PARAMS)
    text = TINY_SWEEP.replace("[envelope]", f"""[model]
casadi = "{model}"
path = "{USER}"
states = ["X", "Y", "psi", "vy", "r"]
inputs = ["delta"]
p = {list(PARAMS)!r}
[params]
{params}
[error]
states = ["vy", "r"]
[envelope]""").replace("'", '"')
    path = folder / "casadi_tiny.toml"
    path.write_text(text)
    return path


def test_a_sweep_of_the_casadi_bicycle_equals_the_jax_bicycles_limits(tiny_sweep, tmp_path,
                                                                      capsys):
    jax_config, jax_folder = tiny_sweep
    bicycle().save(str(tmp_path / "bicycle.casadi"))
    saved = casadi_config(tmp_path, str(tmp_path / "bicycle.casadi"))
    run_sweep(load(saved), tmp_path / "out", progress=False)
    got = pd.read_parquet(tmp_path / "out" / "limits.parquet")
    want = pd.read_parquet(jax_folder / "limits.parquet")
    assert len(got) == len(want) == 4
    for col in ("h_pred", "h_meas", "order_fit", "t_bind", "rho_max"):
        np.testing.assert_allclose(got[col], want[col], rtol=1e-9, err_msg=col)
    assert (got["limit_cause"] == want["limit_cause"]).all()
    # ... and the commands that take a config see it as the JAX bicycle: `stepzoo stability`.
    predicted = []
    for config in (saved, jax_config):
        assert stepzoo(["stability", str(config), "--format", "json"]) == 0
        predicted.append(json.loads(capsys.readouterr().out)["methods"])
    for name, limit in predicted[1].items():
        want_h = limit["max_stable_step"]          # None: no limit (A-stable)
        assert predicted[0][name]["max_stable_step"] == \
            (want_h if want_h is None else pytest.approx(want_h, rel=1e-9)), name
    # The module:function form gives the same function: the same right-hand side object.
    assert load(casadi_config(tmp_path, "casadi_bicycle:bicycle")).spec.rhs is \
        load(saved).spec.rhs


BAD_MODULE = '''import casadi as ca
def not_a_function():
    return 3.0
def two_states():
    x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 7)
    return ca.Function("two", [x, u, p], [x * u * p[0]])
def one_input():
    x = ca.SX.sym("x", 5)
    return ca.Function("one", [x], [x])
'''


@pytest.mark.parametrize("model, words", [
    ("bad_casadi:not_a_function", "returned a float, not a casadi.Function"),
    ("bad_casadi:two_states", "input 0 (x, 'i0') is 2x1, but the model has 5 values of x"),
    ("bad_casadi:one_input", "none of them u (1 values)"),
    ("bad_casadi:missing", "has no function 'missing'"),
    ("nowhere.casadi", "names no file"),
])
def test_a_casadi_model_that_cannot_be_had_is_one_line_and_exit_2(tmp_path, capsys, model,
                                                                  words, monkeypatch):
    # Each case writes its own bad_casadi.py: the one an earlier case imported would shadow it.
    monkeypatch.delitem(sys.modules, "bad_casadi", raising=False)
    (tmp_path / "bad_casadi.py").write_text(BAD_MODULE)
    config = casadi_config(tmp_path, model).read_text().replace(str(USER), str(tmp_path))
    (tmp_path / "bad.toml").write_text(config)
    assert stepzoo(["sweep", str(tmp_path / "bad.toml"), "--out", str(tmp_path / "o")]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert captured.out == "" and len(lines) == 1 and words in lines[0], captured.err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("edit, words", [
    (lambda t: t.replace('casadi = "', 'rhs = "x:y"\ncasadi = "'), "keep one"),
    (lambda t: t.replace('casadi = "casadi_bicycle:bicycle"', 'rhs = "casadi_bicycle:bicycle"'),
     "drop model.p"),
    (lambda t: t.replace('"Car", "vx"]', '"Car"]'), "model.p (m, Iz, Lf, Lr, Caf, Car)"),
])
def test_a_casadi_table_that_mixes_keys_is_one_line_and_exit_2(tmp_path, capsys, edit, words):
    config = tmp_path / "bad.toml"
    config.write_text(edit(casadi_config(tmp_path, "casadi_bicycle:bicycle").read_text()))
    assert stepzoo(["sweep", str(config), "--out", str(tmp_path / "o")]) == 2
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert captured.out == "" and len(lines) == 1 and words in lines[0], captured.err


def test_a_casadi_module_that_exits_or_prints_at_import_is_told_as_an_rhs_module(tmp_path,
                                                                                 capsys):
    """The import guards of JAX models hold for CasADi ones: sys.exit at import is one line
    and exit 2 (not stepzoo ending with the module's status), and nothing reaches stdout."""
    (tmp_path / "exiting_casadi.py").write_text("print('hello')\nimport sys\nsys.exit(0)\n")
    config = casadi_config(tmp_path, "exiting_casadi:f").read_text().replace(str(USER),
                                                                              str(tmp_path))
    (tmp_path / "exit.toml").write_text(config)
    assert stepzoo(["sweep", str(tmp_path / "exit.toml"), "--out", str(tmp_path / "o")]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "exited during import (SystemExit 0)" in captured.err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("at, bit", [(1288, 16), (0, 255)])
def test_a_saved_function_with_one_byte_changed_is_one_line_and_exit_2(tmp_path, at, bit):
    """The third battery's case: CasADi's own deserializer checks some bytes only, and the
    bicycle's saved file with byte 1288 changed killed the process (SIGSEGV) in
    casadi.Function.load; byte 0 changed is the loader's own error. Whatever the loader does
    with a changed byte (crash, error, or a function it loads), the command refuses in one
    line or runs; it never dies (run in a process of its own, as the crash would take pytest
    with it)."""
    import subprocess
    bicycle().save(str(tmp_path / "bicycle.casadi"))
    data = bytearray((tmp_path / "bicycle.casadi").read_bytes())
    data[at] ^= bit
    (tmp_path / "bicycle.casadi").write_bytes(bytes(data))
    config = casadi_config(tmp_path, str(tmp_path / "bicycle.casadi"))
    proc = subprocess.run([sys.executable, "-m", "stepzoo", "stability", str(config)], capture_output=True, text=True,
                          timeout=300)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode in (0, 2), proc.stderr[-2000:]
    if proc.returncode == 2:
        assert len(lines) == 1 and "model.casadi" in lines[0], proc.stderr


def test_what_a_casadi_factory_prints_goes_to_stderr_not_into_the_json(tmp_path, capsys):
    (tmp_path / "chatty_casadi.py").write_text(
        "from casadi_bicycle import bicycle\n\n\ndef chatty():\n"
        "    print('building the bicycle')\n    return bicycle()\n")
    config = casadi_config(tmp_path, "chatty_casadi:chatty").read_text().replace(
        f'path = "{USER}"', f'path = "{tmp_path}"')
    (tmp_path / "chatty.toml").write_text(config)
    sys.path.insert(0, str(USER))         # where the factory finds casadi_bicycle
    try:
        assert stepzoo(["stability", str(tmp_path / "chatty.toml"), "--format", "json"]) == 0
    finally:
        sys.path.remove(str(USER))
    captured = capsys.readouterr()
    assert "euler" in json.loads(captured.out)["methods"]
    assert "building the bicycle" in captured.err


CHAIN = '''import casadi as ca


def chain():
    """x' = (x1, -x0 + 1e-6 e): e a chain of {n} sin-and-affine steps of x0 (4 each)."""
    x, u = ca.SX.sym("x", 2), ca.SX.sym("u", 1)
    e = x[0]
    for _ in range({n}):
        e = ca.sin(e) * 0.999 + 0.001 * x[1]
    return ca.Function("chain", [x, u], [ca.vertcat(x[1], -x[0] + 1e-6 * e)])
'''


def test_a_casadi_model_past_the_instruction_limit_is_one_line_not_a_crash(tmp_path, capsys,
                                                                          monkeypatch):
    """A long expression chain (the issue's had about 9000 instructions) compiled for tens of
    minutes, then crashed XLA's compiler (SIGSEGV): refused in one line before any compile."""
    from stepzoo.dynamics.casadi_model import MAX_INSTRUCTIONS
    monkeypatch.delitem(sys.modules, "long_chain", raising=False)
    (tmp_path / "long_chain.py").write_text(CHAIN.format(n=MAX_INSTRUCTIONS // 4 + 10))
    config = two_state_config(tmp_path, "long_chain:chain", tmp_path)
    assert stepzoo(["stability", str(config)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"more than the {MAX_INSTRUCTIONS}" in lines[0], lines
