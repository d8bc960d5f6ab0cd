use flatland_core::gti::GtiConfig;
use flatland_host::heights::run_gti;
use flatland_host::recording::Recording;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let rec = Recording::open(&args[1]).unwrap();
    let line: usize = args[2].parse().unwrap();
    run_gti(&rec, GtiConfig::default(), |frame, gti| {
        let mut e: Vec<_> = gti.line_edges(line).into_iter().collect();
        e.sort_by(|a, b| a.0.total_cmp(&b.0));
        let v: Vec<String> = e.iter().map(|(r, s, up)| format!("{:.1}{}{:.0}", r, if *up { "+" } else { "-" }, s)).collect();
        let (vals, valid) = gti.line_samples(line).unwrap();
        println!("{frame} [{valid:?}]: {}", v.join(" "));
        if frame == 30 { println!("{:?}", &vals[valid]); }
    }).unwrap();
}
