"""The indirect method and the datasets from Python: a solve's physics checked against the
Rust environment's independent propagation, a generated family equal to its solves one by
one and to `ground data generate`'s files."""

import os
import subprocess
from pathlib import Path

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


def test_a_spacecraft_is_solved_for_recorded_and_checked_on_resume(tmp_path):
    """Twice the specific impulse: the mass flow follows that spacecraft's exhaust speed, the
    optimum keeps more mass, the dataset records the spacecraft and a resume with another is
    refused with the folder unchanged."""
    thesis = lowthrust.spacecraft()
    frugal = lowthrust.spacecraft(isp_s=2 * 3872.0)
    assert frugal["thrust"] == thesis["thrust"]
    assert frugal["exhaust_speed"] == pytest.approx(2 * thesis["exhaust_speed"], rel=1e-15)
    # Converted with the units of the family's central body: a 1 AU Sun-centred one here.
    assert lowthrust.spacecraft("rendezvous-circular", isp_s=7744.0) == frugal

    record = lowthrust.solve("transfer-circular", 7, 0, final_eps=0.3, isp_s=7744.0)
    assert record["converged"], record["failure"]
    eph = record["ephemeris"]
    integrate = getattr(np, "trapezoid", None) or np.trapz
    spent = frugal["thrust"] / frugal["exhaust_speed"] * integrate(eph["throttle"], eph["t"])
    assert 1.0 - record["final_mass"] == pytest.approx(spent, rel=1e-4)
    assert record["final_mass"] > lowthrust.solve("transfer-circular", 7, 0, final_eps=0.3)["final_mass"]

    out = tmp_path / "frugal"
    lowthrust.generate("rendezvous-circular", 7, 2, out, final_eps=0.3, isp_s=7744.0)
    data = lowthrust.read_dataset(out)
    assert data["spacecraft"] == frugal
    solved = lowthrust.solve("rendezvous-circular", 7, 1, final_eps=0.3, isp_s=7744.0)
    assert data["final_mass"][1] == solved["final_mass"]
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    with pytest.raises(lowthrust.LowThrustError, match="spacecraft"):
        lowthrust.generate("rendezvous-circular", 7, 3, out, final_eps=0.3)
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before

    ground = os.environ.get("LOWTHRUST_GROUND")
    if ground is not None:
        # The command line solves the same records for the same spacecraft.
        subprocess.run(
            [ground, "data", "generate", "--scenario", "rendezvous-circular", "--count", "2",
             "--seed", "7", "--final-eps", "0.3", "--isp-s", "7744", "--out", str(tmp_path / "cli")],
            check=True,
            capture_output=True,
        )
        subprocess.run(
            [ground, "data", "compare", str(out / "dataset.ltds"), str(tmp_path / "cli" / "dataset.ltds")],
            check=True,
        )


def test_an_inclined_family_is_generated_in_three_dimensions(tmp_path):
    """Zavoli and Federici's Earth-Mars rendezvous with their spacecraft: records in three
    dimensions whose masses end near the study's optimum (603.556 kg of 1,000), departing from
    the environment's own state, as the command line writes them."""
    family = str(Path(__file__).resolve().parents[2] / "configs" / "missions" / "earth-mars.toml")
    study = {"thrust_n": 0.5, "isp_s": 2000.0, "mass_kg": 1000.0}
    summary = lowthrust.generate(family, 7, 2, tmp_path / "em", final_eps=0.004, **study)
    assert summary["converged"] == 2
    data = lowthrust.read_dataset(tmp_path / "em")
    assert data["spacecraft"] == lowthrust.spacecraft(family, **study)
    assert data["costates"].shape == (2, 7) and "direction_polar" not in data
    assert data["state"].shape == (data["offsets"][-1], 7)
    # Within 0.005 of the optimum: the homotopy stops at eps 0.004, the departures are dispersed.
    assert abs(data["final_mass"].mean() - 0.603556) < 5e-3
    # One draw solved alone is the dataset's record, bit for bit; Mars's orbit is inclined.
    record = lowthrust.solve(family, 7, 1, final_eps=0.004, **study)
    assert record["final_mass"] == data["final_mass"][1]
    assert np.array_equal(record["costates"], data["costates"][1])
    rows = slice(data["offsets"][1], data["offsets"][2])
    assert np.array_equal(record["steps"]["state"], data["state"][rows])
    assert np.array_equal(record["steps"]["direction"], data["direction"][rows])
    assert record["scenario"] == lowthrust.draw_scenario(family, 7, 1)
    assert record["scenario"]["target_plane"]["inclination"] > np.radians(1.0)
    env = lowthrust.Env(family, "[spacecraft]\nmax_thrust_n = 0.5\nisp_s = 2000.0\ninitial_mass_kg = 1000.0")
    for i in range(2):
        rows = slice(data["offsets"][i], data["offsets"][i + 1])
        state, throttle = data["state"][rows], data["throttle"][rows]
        assert state.shape[0] == data["steps"][i] + 1
        env.reset(7, i)
        np.testing.assert_allclose(state[0], env.state, rtol=0, atol=1e-12)
        assert state[-1, 6] == pytest.approx(data["final_mass"][i], abs=1e-9)
        assert np.all(np.diff(state[:, 6]) <= 0)
        on = throttle > 1e-3
        np.testing.assert_allclose(np.linalg.norm(data["direction"][rows][on], axis=1), 1.0, atol=1e-9)

    ground = os.environ.get("LOWTHRUST_GROUND")
    if ground is not None:
        subprocess.run(
            [ground, "data", "generate", "--scenario", family, "--count", "2", "--seed", "7",
             "--final-eps", "0.004", "--thrust-n", "0.5", "--isp-s", "2000", "--mass-kg", "1000",
             "--out", str(tmp_path / "cli")],
            check=True,
            capture_output=True,
        )
        subprocess.run(
            [ground, "data", "compare", str(tmp_path / "em" / "dataset.ltds"),
             str(tmp_path / "cli" / "dataset.ltds")],
            check=True,
        )


def test_bad_solver_input_is_refused(tmp_path):
    with pytest.raises(lowthrust.LowThrustError, match="final_eps"):
        lowthrust.solve("transfer-circular", 7, 0, final_eps=0.0)
    with pytest.raises(lowthrust.LowThrustError, match="neither a scenario family preset"):
        lowthrust.draw_scenario("transfer-elliptic", 1, 0)
    with pytest.raises(lowthrust.LowThrustError):
        lowthrust.read_dataset("/nonexistent/dataset")
    with pytest.raises(OverflowError):
        lowthrust.draw_scenario("transfer-circular", -1, 0)
    with pytest.raises(lowthrust.LowThrustError, match="maximum thrust must be finite and > 0 N"):
        lowthrust.solve("transfer-circular", 7, 0, thrust_n=-1.0)
    with pytest.raises(lowthrust.LowThrustError, match="initial mass must be finite and > 0 kg"):
        lowthrust.spacecraft(mass_kg=float("nan"))
    with pytest.raises(lowthrust.LowThrustError, match="specific impulse must be finite and > 0 s"):
        lowthrust.generate("transfer-circular", 7, 1, tmp_path / "refused", isp_s=0.0)
    assert not (tmp_path / "refused").exists()
