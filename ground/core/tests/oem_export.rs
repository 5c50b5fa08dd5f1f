//! CCSDS OEM export: round trip through our strict reader and through an independent parser
//! (`ccsds-ndm`), frame rotation, epochs, the thrust profile, and refusals.
//!
//! The checks recompute what they can without the module's code: the obliquity rotation, the
//! calendar arithmetic of the epochs and the unit conversions are done again here.

use std::f64::consts::PI;

use ccsds_ndm::messages::oem::Oem;
use ccsds_ndm::traits::{Ndm, Validate};
use ground_core::oem::{read_oem, write_oem, write_thrust_csv, CalendarEpoch, OemError, OemOptions, THRUST_CSV_HEADER};
use ground_core::solver::record::{TrajectoryRecord, TrajectorySample};
use shared::scenario::ScenarioKind;
use shared::spacecraft::Spacecraft;
use shared::units::{AU_M, TIME_UNIT_S, VELOCITY_UNIT_M_S};

const N: usize = 100;
const DEPARTURE: &str = "2030-07-01T00:00:00";
/// J2000 obliquity, 84381.448 arcsec, restated here on purpose.
const OBLIQUITY_DEG: f64 = 23.0 + 26.0 / 60.0 + 21.448 / 3600.0;

/// A converged-looking record flying one revolution of the circular 1 AU orbit, mass falling
/// linearly from 1 to 0.7, throttle cycling 0, 0.5, 1, thrust along-track.
fn circular_record() -> TrajectoryRecord {
    let tof = 2.0 * PI;
    let ephemeris: Vec<TrajectorySample> = (0..N)
        .map(|k| {
            let t = tof * k as f64 / (N - 1) as f64;
            TrajectorySample {
                t,
                r: [t.cos(), t.sin()],
                v: [-t.sin(), t.cos()],
                m: 1.0 - 0.3 * t / tof,
                throttle: [0.0, 0.5, 1.0][k % 3],
                direction: [-t.sin(), t.cos()],
                direction_polar: [0.0, 1.0],
            }
        })
        .collect();
    TrajectoryRecord {
        family: ScenarioKind::TransferCircular.family(),
        seed: 7,
        index: 3,
        scenario: ScenarioKind::TransferCircular.draw(7, 3),
        converged: true,
        failure: None,
        costates: [0.1, -0.2, 0.3, -0.4, 0.5],
        final_anomaly: Some(1.0),
        final_eps: 6.1e-5,
        final_mass: 0.7,
        thrust_arcs: 33,
        residual: 3e-10,
        seconds: 1.5,
        ephemeris,
        steps: Vec::new(),
        distinct_energy_optima: 1,
    }
}

fn options() -> OemOptions {
    OemOptions {
        object_name: "MSR ERO".into(),
        object_id: "UNKNOWN".into(),
        originator: "UMD".into(),
        departure_epoch: CalendarEpoch::parse(DEPARTURE).unwrap(),
        creation_date: CalendarEpoch::from_calendar(2026, 5, 1, 12, 30, 15.25).unwrap(),
        spacecraft: Spacecraft::MSR_ERO,
    }
}

fn oem_text(record: &TrajectoryRecord) -> String {
    let mut out = Vec::new();
    write_oem(record, &options(), &mut out).unwrap();
    String::from_utf8(out).unwrap()
}

/// Equatorial (EME2000) to J2000 ecliptic, written out independently of the module.
fn to_ecliptic(v: [f64; 3]) -> [f64; 3] {
    let e = OBLIQUITY_DEG.to_radians();
    [v[0], e.cos() * v[1] + e.sin() * v[2], -e.sin() * v[1] + e.cos() * v[2]]
}

fn norm(v: [f64; 3]) -> f64 {
    (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Seconds from 2030-07-01T00:00:00 to an ISO epoch string, by counting days month by month.
fn seconds_after_departure(iso: &str) -> f64 {
    let num = |a: usize, b: usize| iso[a..b].parse::<u32>().unwrap();
    let (year, month, day) = (num(0, 4), num(5, 7), num(8, 10));
    let month_days = |y: u32, m: u32| match m {
        2 if y.is_multiple_of(4) && (!y.is_multiple_of(100) || y.is_multiple_of(400)) => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    };
    let (mut y, mut m, mut days) = (2030, 7, 0u32);
    while (y, m) != (year, month) {
        days += month_days(y, m);
        (y, m) = if m == 12 { (y + 1, 1) } else { (y, m + 1) };
    }
    days += day - 1;
    let seconds: f64 = iso[17..].parse().unwrap();
    f64::from(days) * 86_400.0 + f64::from(num(11, 13) * 3600 + num(14, 16) * 60) + seconds
}

/// The data lines of an OEM text: (epoch string, six numbers).
fn data_lines(text: &str) -> Vec<(String, [f64; 6])> {
    let after_meta = text.split("META_STOP").nth(1).unwrap();
    after_meta
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("COMMENT"))
        .map(|l| {
            let f: Vec<&str> = l.split_whitespace().collect();
            assert_eq!(f.len(), 7, "data line {l}");
            let x: Vec<f64> = f[1..].iter().map(|s| s.parse().unwrap()).collect();
            (f[0].to_string(), [x[0], x[1], x[2], x[3], x[4], x[5]])
        })
        .collect()
}

#[test]
fn circular_orbit_round_trips_in_eme2000_with_exact_epochs() {
    let record = circular_record();
    let text = oem_text(&record);
    let lines = data_lines(&text);
    assert_eq!(lines.len(), N);
    let km_per_au = AU_M / 1000.0;
    let km_s_per_unit = VELOCITY_UNIT_M_S / 1000.0;
    let eps = OBLIQUITY_DEG.to_radians();
    let mut previous = f64::NEG_INFINITY;
    for ((epoch, x), s) in lines.iter().zip(&record.ephemeris) {
        // Epochs: strictly increasing, departure + t * t* to 1 ms (calendar arithmetic redone here).
        let dt = seconds_after_departure(epoch);
        assert!(dt > previous, "epochs not increasing at {epoch}");
        previous = dt;
        assert!(
            (dt - s.t * TIME_UNIT_S).abs() < 1e-3,
            "{epoch}: {dt} vs {}",
            s.t * TIME_UNIT_S
        );

        let (r_km, v_km_s) = ([x[0], x[1], x[2]], [x[3], x[4], x[5]]);
        // |r| = 1 AU in km.
        assert!((norm(r_km) / km_per_au - 1.0).abs() < 1e-9, "|r| = {} km", norm(r_km));
        // Back to the ecliptic and canonical units: the original planar state, z = 0.
        let r = to_ecliptic(r_km).map(|c| c / km_per_au);
        let v = to_ecliptic(v_km_s).map(|c| c / km_s_per_unit);
        let dr = norm([r[0] - s.r[0], r[1] - s.r[1], r[2]]);
        let dv = norm([v[0] - s.v[0], v[1] - s.v[1], v[2]]);
        assert!(dr < 1e-9 && dv < 1e-9, "{epoch}: dr {dr:e} dv {dv:e} (relative to 1)");
        // Angular momentum tilted from +Z by the obliquity, node on +X (the equinox).
        let h = cross(r_km, v_km_s);
        let tilt = (h[2] / norm(h)).acos();
        assert!((tilt - eps).abs() < 1e-9, "tilt {} deg", tilt.to_degrees());
        let expected = [0.0, -eps.sin(), eps.cos()];
        assert!(
            norm([
                h[0] / norm(h),
                h[1] / norm(h) - expected[1],
                h[2] / norm(h) - expected[2]
            ]) < 1e-9
        );
    }
    // One revolution of the 1 AU circle lasts a year: the last epoch is 2031-07-01 + ~6 h.
    assert!(lines[N - 1].0.starts_with("2031-07-01T06:"), "{}", lines[N - 1].0);
    assert_eq!(lines[0].0, "2030-07-01T00:00:00.000000");

    // KVN layout: version first, one metadata block, short printable lines.
    assert_eq!(text.lines().next(), Some("CCSDS_OEM_VERS = 2.0"));
    assert_eq!(text.matches("META_START").count(), 1);
    assert_eq!(text.matches("META_STOP").count(), 1);
    for l in text.lines() {
        assert!(
            l.len() <= 254 && l.bytes().all(|b| (b' '..=b'~').contains(&b)),
            "bad line '{l}'"
        );
    }
}

#[test]
fn strict_reader_returns_metadata_states_and_thrust_profile() {
    let record = circular_record();
    let opts = options();
    let oem = read_oem(&oem_text(&record)).unwrap();
    assert_eq!(oem.version, "2.0");
    assert_eq!(oem.originator, "UMD");
    assert_eq!(oem.creation_date.to_string(), "2026-05-01T12:30:15.250000");
    let m = &oem.metadata;
    assert_eq!(m.object_name, "MSR ERO");
    assert_eq!(m.object_id, "UNKNOWN");
    assert_eq!(m.center_name, "SUN");
    assert_eq!(m.ref_frame, "EME2000");
    assert_eq!(m.time_system, "TDB");
    assert!(
        m.comments.iter().any(|c| c.contains("84381.448")),
        "the frame rotation is documented"
    );
    assert_eq!(oem.states.len(), N);
    assert_eq!(m.start_time, oem.states[0].epoch);
    assert_eq!(m.stop_time, oem.states[N - 1].epoch);
    assert_eq!(m.useable_start_time, Some(m.start_time));
    assert_eq!(m.useable_stop_time, Some(m.stop_time));
    assert_eq!(m.interpolation.as_deref(), Some("HERMITE"));
    assert!(matches!(m.interpolation_degree, Some(d) if d >= 1 && (d as usize) < N));
    assert!(oem
        .header_comments
        .iter()
        .any(|c| c.contains("transfer-circular seed 7 index 3")));
    for (state, s) in oem.states.iter().zip(&record.ephemeris) {
        let dt = state.epoch.seconds_since(opts.departure_epoch);
        assert!((dt - s.t * TIME_UNIT_S).abs() < 1e-3);
        let (r, v) = state.canonical_ecliptic();
        assert!((r[0] - s.r[0]).abs() < 1e-9 && (r[1] - s.r[1]).abs() < 1e-9 && r[2].abs() < 1e-12);
        assert!((v[0] - s.v[0]).abs() < 1e-9 && (v[1] - s.v[1]).abs() < 1e-9 && v[2].abs() < 1e-12);
    }
    // The thrust comments carry one row per state with the states' epochs.
    let profile = oem.thrust_profile().unwrap();
    assert_eq!(profile.len(), N);
    for (row, s) in profile.iter().zip(&record.ephemeris) {
        assert!((row.thrust_n - s.throttle * 1.33).abs() < 1e-11);
        assert!((row.mass_kg - s.m * 3366.0).abs() < 1e-6);
    }
}

#[test]
fn an_independent_ccsds_parser_accepts_the_message() {
    let record = circular_record();
    let text = oem_text(&record);
    let ours = read_oem(&text).unwrap();
    // ccsds-ndm parses in strict validation mode and checks obligatory keywords and versions.
    let theirs = Oem::from_kvn(&text).unwrap_or_else(|e| panic!("ccsds-ndm refused the OEM: {e}"));
    theirs.validate().unwrap();
    assert_eq!(theirs.version, "2.0");
    assert_eq!(theirs.header.originator, "UMD");
    assert_eq!(theirs.body.segment.len(), 1);
    let segment = &theirs.body.segment[0];
    let m = &segment.metadata;
    assert_eq!(
        (m.object_name.as_str(), m.object_id.as_str(), m.center_name.as_str()),
        ("MSR ERO", "UNKNOWN", "SUN")
    );
    assert_eq!((m.ref_frame.as_str(), m.time_system.as_str()), ("EME2000", "TDB"));
    assert_eq!(m.start_time.as_str(), ours.metadata.start_time.to_string());
    assert_eq!(m.stop_time.as_str(), ours.metadata.stop_time.to_string());
    assert_eq!(m.interpolation.as_deref(), Some("HERMITE"));
    assert!(m.interpolation_degree.is_some());
    assert_eq!(
        segment.data.comment.len(),
        N + 2,
        "two description lines and one thrust line per state"
    );
    assert_eq!(segment.data.state_vector.len(), N);
    for (sv, state) in segment.data.state_vector.iter().zip(&ours.states) {
        assert_eq!(sv.epoch.as_str(), state.epoch.to_string());
        let theirs = [
            sv.x.value,
            sv.y.value,
            sv.z.value,
            sv.x_dot.value,
            sv.y_dot.value,
            sv.z_dot.value,
        ];
        let ours = [state.position_km, state.velocity_km_s].concat();
        for (a, b) in theirs.iter().zip(&ours) {
            assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "{a} vs {b}");
        }
    }
}

#[test]
fn thrust_csv_has_one_row_per_sample_in_si_units() {
    let record = circular_record();
    let mut out = Vec::new();
    write_thrust_csv(&record, &options(), &mut out).unwrap();
    let csv = String::from_utf8(out).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next(), Some(THRUST_CSV_HEADER));
    assert_eq!(
        THRUST_CSV_HEADER,
        "epoch_iso,t_days,mass_kg,throttle,thrust_N,dir_x,dir_y,dir_z"
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), N);
    let oem_epochs: Vec<String> = data_lines(&oem_text(&record)).into_iter().map(|(e, _)| e).collect();
    let oem_profile = read_oem(&oem_text(&record)).unwrap().thrust_profile().unwrap();
    for (k, (row, s)) in rows.iter().zip(&record.ephemeris).enumerate() {
        assert_eq!(row.len(), 8);
        assert_eq!(row[0], oem_epochs[k], "CSV and OEM epochs agree");
        let x: Vec<f64> = row[1..].iter().map(|c| c.parse().unwrap()).collect();
        let (t_days, mass_kg, throttle, thrust) = (x[0], x[1], x[2], x[3]);
        assert!((t_days - s.t * TIME_UNIT_S / 86_400.0).abs() < 1e-8);
        assert!((seconds_after_departure(row[0]) / 86_400.0 - t_days).abs() < 1e-7);
        assert!((mass_kg - s.m * 3366.0).abs() < 1e-6, "mass column in kg");
        assert!((throttle - s.throttle).abs() < 1e-12);
        assert!((thrust - throttle * 1.33).abs() < 1e-11, "thrust = throttle * Tmax");
        // Direction: a unit vector in EME2000 that rotates back onto the planar direction.
        let d = to_ecliptic([x[4], x[5], x[6]]);
        assert!((d[0] - s.direction[0]).abs() < 1e-11 && (d[1] - s.direction[1]).abs() < 1e-11 && d[2].abs() < 1e-11);
        // The OEM comment lines carry the same row.
        let p = &oem_profile[k];
        assert_eq!(p.epoch.to_string(), row[0]);
        assert!((p.thrust_n - thrust).abs() < 1e-12 && (p.mass_kg - mass_kg).abs() < 1e-9);
    }
    // The mass falls by the expected 30 % over the flight.
    let last_mass: f64 = rows[N - 1][2].parse().unwrap();
    assert!((last_mass - 0.7 * 3366.0).abs() < 1e-6);
}

fn refusal(record: &TrajectoryRecord, opts: &OemOptions) -> OemError {
    let (mut oem, mut csv) = (Vec::new(), Vec::new());
    let e = write_oem(record, opts, &mut oem).unwrap_err();
    assert!(write_thrust_csv(record, opts, &mut csv).is_err());
    assert!(oem.is_empty() && csv.is_empty(), "nothing is written on refusal");
    assert!(!e.to_string().is_empty());
    e
}

#[test]
fn unconverged_empty_and_non_finite_records_are_refused() {
    let opts = options();
    let mut record = circular_record();
    record.converged = false;
    record.failure = Some("homotopy stalled at eps 0.25".into());
    let e = refusal(&record, &opts);
    assert!(matches!(e, OemError::NotConverged { .. }), "{e:?}");
    assert!(e.to_string().contains("unconverged") && e.to_string().contains("homotopy stalled"));

    let mut record = circular_record();
    record.ephemeris.clear();
    assert!(matches!(refusal(&record, &opts), OemError::NoSamples));

    let mut record = circular_record();
    record.ephemeris[42].r[1] = f64::NAN;
    let e = refusal(&record, &opts);
    assert!(
        matches!(
            e,
            OemError::NonFinite {
                index: 42,
                field: "position"
            }
        ),
        "{e:?}"
    );
    assert!(e.to_string().contains("42"));

    let mut record = circular_record();
    record.ephemeris[7].v[0] = f64::INFINITY;
    assert!(matches!(
        refusal(&record, &opts),
        OemError::NonFinite {
            index: 7,
            field: "velocity"
        }
    ));

    let mut record = circular_record();
    record.ephemeris[99].m = f64::NAN;
    assert!(matches!(
        refusal(&record, &opts),
        OemError::NonFinite {
            index: 99,
            field: "mass"
        }
    ));

    let mut record = circular_record();
    record.ephemeris[10].t = record.ephemeris[9].t;
    assert!(matches!(
        refusal(&record, &opts),
        OemError::TimeNotIncreasing { index: 10 }
    ));

    let mut record = circular_record();
    record.ephemeris[3].throttle = 1.5;
    assert!(matches!(
        refusal(&record, &opts),
        OemError::InvalidSample { index: 3, .. }
    ));

    let record = circular_record();
    let mut bad = options();
    bad.object_name = "MSR\nERO".into();
    assert!(matches!(
        refusal(&record, &bad),
        OemError::InvalidOption {
            field: "OBJECT_NAME",
            ..
        }
    ));
    let mut bad = options();
    bad.originator = String::new();
    assert!(matches!(
        refusal(&record, &bad),
        OemError::InvalidOption {
            field: "ORIGINATOR",
            ..
        }
    ));
    let mut bad = options();
    bad.spacecraft.max_thrust_n = 0.0;
    assert!(matches!(refusal(&record, &bad), OemError::Spacecraft(_)));
}

#[test]
fn strict_reader_refuses_what_the_standard_forbids() {
    let good = oem_text(&circular_record());
    assert!(read_oem(&good).is_ok());
    let data: Vec<&str> = good
        .lines()
        .filter(|l| l.starts_with("2030-") || l.starts_with("2031-"))
        .collect();
    let cases: Vec<(&str, String)> = vec![
        ("empty", String::new()),
        ("missing OBJECT_ID", good.replace("OBJECT_ID = UNKNOWN\n", "")),
        (
            "keywords out of order",
            good.replace(
                "OBJECT_ID = UNKNOWN\nCENTER_NAME = SUN\n",
                "CENTER_NAME = SUN\nOBJECT_ID = UNKNOWN\n",
            ),
        ),
        (
            "unknown keyword",
            good.replace("CENTER_NAME = SUN\n", "CENTER_NAME = SUN\nFOO = 1\n"),
        ),
        (
            "repeated keyword",
            good.replace("REF_FRAME = EME2000\n", "REF_FRAME = EME2000\nREF_FRAME = ICRF\n"),
        ),
        (
            "wrong version keyword",
            good.replace("CCSDS_OEM_VERS", "CCSDS_OPM_VERS"),
        ),
        (
            "bad version",
            good.replace("CCSDS_OEM_VERS = 2.0", "CCSDS_OEM_VERS = 9.9"),
        ),
        (
            "bad epoch",
            good.replace(
                "START_TIME = 2030-07-01T00:00:00.000000",
                "START_TIME = 2030-02-30T00:00:00",
            ),
        ),
        (
            "six fields",
            good.replacen(data[5], &data[5][..data[5].rfind(' ').unwrap()], 1),
        ),
        (
            "not a number",
            good.replacen(data[5], &format!("{} 1 2 3 4 5 nan", &data[5][..26]), 1),
        ),
        ("epochs out of order", good.replacen(data[5], data[4], 1)),
        (
            "epoch after STOP_TIME",
            format!("{good}2040-01-01T00:00:00.000000 1 2 3 4 5 6\n"),
        ),
        ("comment after data", format!("{good}COMMENT late\n")),
        ("second segment", format!("{good}META_START\n")),
        (
            "interpolation without degree",
            good.replace("INTERPOLATION_DEGREE = 5\n", ""),
        ),
    ];
    for (what, text) in cases {
        assert_ne!(text, good, "case '{what}' did not change the text");
        match read_oem(&text) {
            Err(OemError::Parse { .. }) => {}
            other => panic!("case '{what}': expected a parse error, got {other:?}"),
        }
    }
}

#[test]
fn calendar_epochs_follow_the_gregorian_calendar() {
    let p = |s: &str| CalendarEpoch::parse(s).unwrap();
    assert_eq!(CalendarEpoch::J2000.to_string(), "2000-01-01T12:00:00.000000");
    assert_eq!(p("2000-01-01T12:00:00"), CalendarEpoch::J2000);
    // 2000 is a leap year (divisible by 400), 2100 and 1900 are not.
    assert_eq!(
        CalendarEpoch::J2000.plus_seconds(366.0 * 86_400.0).unwrap(),
        p("2001-01-01T12:00:00")
    );
    assert_eq!(
        p("2024-02-28T23:59:59.5").plus_seconds(1.0).unwrap().to_string(),
        "2024-02-29T00:00:00.500000"
    );
    for bad in [
        "2100-02-29T00:00:00",
        "1900-02-29T00:00:00",
        "2030-13-01T00:00:00",
        "2030-04-31T00:00:00",
    ] {
        assert!(CalendarEpoch::parse(bad).is_err(), "{bad}");
    }
    for bad in [
        "2030-01-01 00:00:00",
        "2030-01-01T24:00:00",
        "2030-01-01T00:00:00Z",
        "2030-01-01T00:00:00.",
    ] {
        assert!(CalendarEpoch::parse(bad).is_err(), "{bad}");
    }
    // Unix time: 2000-02-29T00:00:00 UTC is 951,782,400 s.
    assert_eq!(
        CalendarEpoch::from_unix_seconds(951_782_400.0).unwrap(),
        p("2000-02-29T00:00:00")
    );
    assert_eq!(
        CalendarEpoch::from_unix_seconds(0.0).unwrap().to_string(),
        "1970-01-01T00:00:00.000000"
    );
    // Rounding to the microsecond carries into the next year.
    assert_eq!(
        p("2030-12-31T23:59:59.9999996").to_string(),
        "2031-01-01T00:00:00.000000"
    );
    assert_eq!(
        p("2030-06-15T08:09:10.123456789").to_string(),
        "2030-06-15T08:09:10.123457"
    );
    let a = p("2030-07-01T00:00:00");
    let b = p("2031-07-01T06:09:09.761");
    assert!((b.seconds_since(a) - (365.0 * 86_400.0 + 6.0 * 3600.0 + 9.0 * 60.0 + 9.761)).abs() < 1e-6);
    assert!(a.plus_seconds(f64::NAN).is_err());
}

/// A family around the Earth or Mars is written about that planet, in its own equatorial
/// frame as solved (no rotation: z = 0), its lengths in the planet's radii and its epochs in
/// the planet's time unit sqrt(L^3 / mu), both recomputed here from the constants; an
/// independent parser accepts both; a body given only by mu and a length unit has no name and
/// is refused with its family named.
#[test]
fn earth_and_mars_families_are_written_about_their_planet_in_its_units() {
    use shared::mission::CentralBody;
    // (body, CENTER_NAME, REF_FRAME, equatorial radius m, mu m^3/s^2)
    let cases = [
        (
            CentralBody::EARTH,
            "EARTH",
            "EME2000",
            6_378_137.0_f64,
            3.986_004_418e14_f64,
        ),
        (CentralBody::MARS, "MARS", "MCI", 3_396_190.0, 4.282_837_362e13),
    ];
    for (body, centre, frame, radius_m, mu) in cases {
        let mut record = circular_record();
        record.family.body = body;
        let text = oem_text(&record);
        let time_unit_s = (radius_m * radius_m * radius_m / mu).sqrt();
        let velocity_km_s = radius_m / time_unit_s / 1000.0;
        let oem = read_oem(&text).unwrap();
        assert_eq!(
            (oem.metadata.center_name.as_str(), oem.metadata.ref_frame.as_str()),
            (centre, frame)
        );
        for (state, s) in oem.states.iter().zip(&record.ephemeris) {
            let dt = state.epoch.seconds_since(options().departure_epoch);
            assert!((dt - s.t * time_unit_s).abs() < 1e-3, "{centre}: {dt}");
            let (r, v) = (state.position_km, state.velocity_km_s);
            assert!(
                r[2] == 0.0 && v[2] == 0.0,
                "{centre}: the planar solution is the frame's x-y plane"
            );
            for k in 0..2 {
                assert!((r[k] - s.r[k] * radius_m / 1000.0).abs() < 1e-6, "{centre}: {r:?}");
                assert!((v[k] - s.v[k] * velocity_km_s).abs() < 1e-9, "{centre}: {v:?}");
            }
        }
        let theirs = Oem::from_kvn(&text).unwrap_or_else(|e| panic!("ccsds-ndm refused the {centre} OEM: {e}"));
        theirs.validate().unwrap();
        assert_eq!(theirs.body.segment[0].metadata.ref_frame, frame);
        assert!(text.contains(&format!("about the {}", centre.to_lowercase())), "{text}");
    }
    let mut custom = circular_record();
    custom.family.body = CentralBody {
        mu_m3_s2: 1.0e19,
        length_unit_m: AU_M,
    };
    let label = custom.family.label().to_string();
    let mut out = Vec::new();
    match write_oem(&custom, &options(), &mut out) {
        Err(OemError::UnnamedCentre(family)) => assert_eq!(family, label),
        other => panic!("{other:?}"),
    }
    assert!(out.is_empty(), "nothing is written for a refused record");
}

/// A three-dimensional record (an inclined family's) is written with its out-of-plane
/// components: the states read back and turned to the ecliptic lie on the inclined circle, the
/// orbit normal of each state is the plane's, and the independent parser takes the message.
#[test]
fn an_inclined_record_is_written_with_its_out_of_plane_components() {
    use ground_core::solver::spatial::record::SpatialRecord;
    use ground_core::solver::spatial::SpatialSample;
    use shared::mission::{PlaneRanges, SpatialFamily};
    use shared::orbit::{CartesianState, OrbitPlane};
    use shared::scenario::{Range, SpatialScenario};
    let plane = OrbitPlane {
        inclination: 30f64.to_radians(),
        raan: 50f64.to_radians(),
    };
    let fixed = |x: f64| Range { lo: x, hi: x };
    let family = SpatialFamily {
        family: ScenarioKind::TransferCircular.family(),
        departure_plane: PlaneRanges {
            inclination: fixed(plane.inclination),
            raan: fixed(plane.raan),
        },
        target_plane: PlaneRanges::REFERENCE,
        departure_dispersion: shared::mission::StateDispersion::NONE,
    };
    let tof = 2.0 * PI;
    let ephemeris: Vec<SpatialSample> = (0..N)
        .map(|k| {
            let t = tof * k as f64 / (N - 1) as f64;
            let state = plane.embed(&CartesianState {
                r: [t.cos(), t.sin()],
                v: [-t.sin(), t.cos()],
            });
            let along = state.v;
            SpatialSample {
                t,
                state,
                m: 1.0 - 0.3 * t / tof,
                throttle: 0.5,
                direction: along,
            }
        })
        .collect();
    let record = SpatialRecord {
        family,
        seed: 7,
        index: 3,
        scenario: SpatialScenario::planar(ScenarioKind::TransferCircular.draw(7, 3)),
        converged: true,
        failure: None,
        costates: [0.0; 7],
        final_anomaly: Some(1.0),
        final_eps: 6.1e-5,
        final_mass: 0.7,
        thrust_arcs: 1,
        residual: 3e-10,
        seconds: 1.5,
        ephemeris,
        steps: Vec::new(),
        distinct_energy_optima: 1,
    };
    let mut out = Vec::new();
    write_oem(&record, &options(), &mut out).unwrap();
    let text = String::from_utf8(out).unwrap();
    let km_per_au = AU_M / 1000.0;
    let km_s = VELOCITY_UNIT_M_S / 1000.0;
    let (si, ci) = plane.inclination.sin_cos();
    let normal = [si * plane.raan.sin(), -si * plane.raan.cos(), ci];
    let lines = data_lines(&text);
    assert_eq!(lines.len(), N);
    for ((_, x), s) in lines.iter().zip(&record.ephemeris) {
        let r = to_ecliptic([x[0], x[1], x[2]]).map(|c| c / km_per_au);
        let v = to_ecliptic([x[3], x[4], x[5]]).map(|c| c / km_s);
        for k in 0..3 {
            assert!(
                (r[k] - s.state.r[k]).abs() * km_per_au < 2e-6,
                "{r:?} vs {:?}",
                s.state.r
            );
            assert!((v[k] - s.state.v[k]).abs() * km_s < 2e-12);
        }
        let h = cross(r, v);
        let n = norm(h);
        assert!(h.iter().zip(normal).all(|(a, b)| (a / n - b).abs() < 1e-9), "{h:?}");
    }
    let theirs = Oem::from_kvn(&text).unwrap_or_else(|e| panic!("ccsds-ndm refused the OEM: {e}"));
    theirs.validate().unwrap();
    assert_eq!(theirs.body.segment[0].data.state_vector.len(), N);
    // The thrust profile carries the inclined direction, a unit vector in EME2000.
    let ours = read_oem(&text).unwrap();
    let profile = ours.thrust_profile().unwrap();
    assert!(profile.iter().all(|row| (norm(row.direction) - 1.0).abs() < 1e-9));
}
