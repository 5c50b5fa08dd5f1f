//! Issue 3 session 6: whether two dataset files hold the same records apart from the `seconds`
//! field (every other field compared through its exact `Debug` text, so NaN equals NaN).
//!
//! cargo run --release -p lowthrust-ground --example same_records -- A/dataset.ltds B/dataset.ltds
use lowthrust_ground::generate::read_dataset;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let load = |p: &str| {
        let mut file = read_dataset(std::path::Path::new(p)).unwrap();
        for r in &mut file.records {
            r.seconds = 0.0;
        }
        file.records
    };
    let (a, b) = (load(&args[0]), load(&args[1]));
    let differ: Vec<u64> = a
        .iter()
        .zip(&b)
        .filter(|(x, y)| format!("{x:?}") != format!("{y:?}"))
        .map(|(x, _)| x.index)
        .collect();
    println!(
        "{} vs {} records; differing apart from seconds: {differ:?}",
        a.len(),
        b.len()
    );
}
