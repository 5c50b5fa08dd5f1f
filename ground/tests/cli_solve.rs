//! `ground data solve` from the outside: bad input is refused with a clear message, and `--json`
//! prints one object with the documented fields.

use std::process::Command;

fn ground(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_ground")).args(args).output().unwrap()
}

#[test]
fn invalid_orbits_and_times_are_refused_with_a_clear_message() {
    for (args, needle) in [
        (vec!["data", "solve", "--a0", "0", "--af", "1.3"], "semi-major axis"),
        (
            vec!["data", "solve", "--a0", "1", "--af", "1.3", "--e0", "1.2"],
            "eccentricity",
        ),
        (vec!["data", "solve", "--a0", "1", "--af", "NaN"], "semi-major axis"),
        (
            vec!["data", "solve", "--a0", "1", "--af", "1.3", "--tof-days", "-14"],
            "tof-days",
        ),
        (
            vec!["data", "solve", "--a0", "1", "--af", "1.3", "--tof-days", "20"],
            "whole number",
        ),
        (
            vec!["data", "solve", "--scenario", "transfer-easy"],
            "neither a scenario family preset",
        ),
        (vec!["data", "solve"], "--scenario"),
    ] {
        let out = ground(&args);
        assert!(!out.status.success(), "{args:?} was accepted");
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}

#[test]
fn json_output_has_the_documented_fields_and_a_physical_solution() {
    let out = ground(&["data", "solve", "--a0", "1", "--af", "1.3", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for key in [
        "converged",
        "final_mass",
        "thrust_arcs",
        "final_eps",
        "residual",
        "seconds",
        "costates",
    ] {
        assert!(v.get(key).is_some(), "missing {key} in {v}");
    }
    assert_eq!(v["costates"].as_array().unwrap().len(), 5);
    // Whatever eps it reached, the solution it reports meets its terminal conditions and is
    // no better than the impulsive Hohmann transfer (1 -> 1.3 AU: m_f <= exp(-0.122416 / c) = 0.908443).
    assert!(v["residual"].as_f64().unwrap() < 1e-8, "{v}");
    let m = v["final_mass"].as_f64().unwrap();
    assert!(m > 0.85 && m < 0.908443, "{v}");
    // The same transfer for a spacecraft of twice the specific impulse: above anything the
    // thesis's spacecraft reaches, below its own Hohmann bound exp(-0.122416 / (2 c)) = 0.953122.
    let out = ground(&["data", "solve", "--a0", "1", "--af", "1.3", "--isp-s", "7744", "--json"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let m = v["final_mass"].as_f64().unwrap();
    assert!(m > 0.908443 && m < 0.953122, "{v}");
}

/// `ground data solve ... | head -c 1`: the reader goes away before the output is written; the CLI
/// ends by SIGPIPE like other Unix tools, not by a panic on the broken pipe.
#[cfg(unix)]
#[test]
fn a_closed_output_pipe_ends_the_cli_quietly() {
    use std::os::unix::process::ExitStatusExt;
    use std::process::Stdio;
    let mut child = Command::new(env!("CARGO_BIN_EXE_ground"))
        .args(["data", "solve", "--a0", "1", "--af", "1.3", "--json"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(out.status.signal(), Some(libc::SIGPIPE), "{:?}: {err}", out.status);
}

/// `ground --help` lists the command groups a user recognises, at most eight entries, and
/// never the commands run only by the tool itself (a relabelling round's Slurm task).
#[test]
fn the_help_lists_groups_not_internal_commands() {
    let out = ground(&["--help"]);
    assert!(out.status.success());
    let help = String::from_utf8_lossy(&out.stdout);
    let commands: Vec<&str> = help
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| !l.trim().is_empty())
        .filter_map(|l| l.split_whitespace().next())
        .collect();
    assert!(commands.contains(&"data"), "{help}");
    assert!(commands.len() <= 8, "{} entries: {commands:?}", commands.len());
    assert!(!help.contains("relabel-shard"), "{help}");
    // The groups hold the commands: `ground data solve --help` exists.
    assert!(ground(&["data", "solve", "--help"]).status.success());
}
