use flatland_core::gti::GtiConfig;
use flatland_host::heights::run_gti;
use flatland_host::recording::Recording;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let rec = Recording::open(&args[1]).unwrap();
    let line: usize = args[2].parse().unwrap();
    run_gti(&rec, GtiConfig::default(), |frame, gti| {
        let mut v: Vec<String> = gti.tracks().filter(|t| t.line == line).map(|t| format!("#{}:{:?}/{:?}/{:?}", t.id, t.observed_row.map(|r| r as i32), t.fitted_row.map(|r| r as i32), t.point.map(|p| (p.h_mm as i32, p.quality)))).collect();
        v.sort();
        println!("{frame}: {}", v.join(" "));
    }).unwrap();
}
