"""The indirect method and the datasets from Python: a solve's physics checked against the
Rust environment's independent propagation, a generated family equal to its solves one by
one and to `ground data generate`'s files."""

import os
import subprocess

import numpy as np
import pytest

import lowthrust


def test_a_solved_transfer_arrives_and_its_mass_follows_the_rocket_equation():
    record = lowthrust.solve("transfer-circular", 7, 0)
    assert record["converged"], record["failure"]
    scenario = lowthrust.draw_scenario("transfer-circular", 7, 0)
    steps = record["steps"]
    n = scenario["steps"]
    assert steps["state"].shape == (n + 1, 5)
    np.testing.assert_allclose(steps["t"], np.arange(n + 1) * lowthrust.STEP, rtol=0, atol=1e-12)
    # Departure: the environment's initial state of the same scenario.
    env = lowthrust.Env("transfer-circular")
    env.reset(7, 0)
    np.testing.assert_allclose(steps["state"][0], env.state, rtol=0, atol=1e-12)
    # Arrival on the target orbit: its energy -1/(2a) and angular momentum sqrt(a (1 - e^2))
    # (mu = 1).
    x, y, vx, vy, m = steps["state"][-1]
    target = scenario["target"]
    a, e = target["a"], target["e"]
    assert (vx**2 + vy**2) / 2 - 1 / np.hypot(x, y) == pytest.approx(-1 / (2 * a), abs=1e-7)
    assert x * vy - y * vx == pytest.approx(np.sqrt(a * (1 - e**2)), abs=1e-7)
    assert m == pytest.approx(record["final_mass"], abs=1e-9)
    # Mass flow m' = -T u / c: the propellant spent is the throttle's integral on the fine grid
    # (of a smooth solution, eps = 0.3: the fuel-optimal one switches faster than the grid).
    smooth = lowthrust.solve("transfer-circular", 7, 0, final_eps=0.3)
    eph = smooth["ephemeris"]
    sc = lowthrust.spacecraft()
    integrate = getattr(np, "trapezoid", None) or np.trapz  # numpy 2, or 1
    spent = sc["thrust"] / sc["exhaust_speed"] * integrate(eph["throttle"], eph["t"])
    assert 1.0 - smooth["final_mass"] == pytest.approx(spent, rel=1e-4)
    # Thrust directions are unit vectors where there is thrust.
    eph = record["ephemeris"]
    on = eph["throttle"] > 1e-3
    np.testing.assert_allclose(np.hypot(*eph["direction"][on].T), 1.0, atol=1e-9)


def test_a_generated_family_reads_back_as_arrays_equal_to_its_solves(tmp_path):
    summary = lowthrust.generate("rendezvous-circular", 7, 3, tmp_path / "d", final_eps=0.3)
    assert summary["records"] == 3
    data = lowthrust.read_dataset(tmp_path / "d")
    assert data["kind"] == "rendezvous-circular" and list(data["index"]) == [0, 1, 2]
    assert data["costates"].shape == (3, 5)
    for i in range(3):
        record = lowthrust.solve("rendezvous-circular", 7, i, final_eps=0.3)
        assert data["converged"][i] == record["converged"]
        assert data["final_mass"][i] == record["final_mass"]
        assert np.array_equal(data["costates"][i], record["costates"])
        rows = slice(data["offsets"][i], data["offsets"][i + 1])
        assert np.array_equal(data["state"][rows], record["steps"]["state"])
        assert np.array_equal(data["throttle"][rows], record["steps"]["throttle"])
        assert data["steps"][i] + 1 == rows.stop - rows.start


def test_the_command_line_writes_the_same_dataset(tmp_path):
    """`ground data generate` and `lowthrust.generate`: the same trajectories (set
    LOWTHRUST_GROUND to the binary; the project's test command does)."""
    ground = os.environ.get("LOWTHRUST_GROUND")
    if ground is None:
        pytest.skip("LOWTHRUST_GROUND is not set")
    lowthrust.generate("transfer-hard", 7, 4, tmp_path / "py", final_eps=0.3)
    subprocess.run(
        [ground, "data", "generate", "--scenario", "transfer-hard", "--count", "4", "--seed", "7",
         "--final-eps", "0.3", "--out", str(tmp_path / "cli")],
        check=True,
        capture_output=True,
    )
    subprocess.run(
        [ground, "data", "compare", str(tmp_path / "py" / "dataset.ltds"), str(tmp_path / "cli" / "dataset.ltds")],
        check=True,
    )
    py, cli = lowthrust.read_dataset(tmp_path / "py"), lowthrust.read_dataset(tmp_path / "cli")
    for key in ["converged", "final_mass", "costates", "state", "throttle", "direction", "offsets"]:
        assert np.array_equal(py[key], cli[key]), key


def test_bad_solver_input_is_refused():
    with pytest.raises(lowthrust.LowThrustError, match="final_eps"):
        lowthrust.solve("transfer-circular", 7, 0, final_eps=0.0)
    with pytest.raises(lowthrust.LowThrustError, match="neither a scenario family preset"):
        lowthrust.draw_scenario("transfer-elliptic", 1, 0)
    with pytest.raises(lowthrust.LowThrustError):
        lowthrust.read_dataset("/nonexistent/dataset")
    with pytest.raises(OverflowError):
        lowthrust.draw_scenario("transfer-circular", -1, 0)
