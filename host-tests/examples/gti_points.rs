use flatland_core::gti::GtiConfig;
use flatland_host::heights::run_gti;
use flatland_host::recording::Recording;
fn main() {
    let args: Vec<String> = std::env::args().collect();
    let rec = Recording::open(&args[1]).unwrap();
    let want: u32 = args[2].parse().unwrap();
    let (x0, x1, z0, z1): (f32, f32, f32, f32) = (args[3].parse().unwrap(), args[4].parse().unwrap(), args[5].parse().unwrap(), args[6].parse().unwrap());
    run_gti(&rec, GtiConfig::default(), |frame, gti| {
        if frame != want { return; }
        for t in gti.tracks() {
            if let Some(p) = t.point {
                if p.x_mm >= x0 && p.x_mm <= x1 && p.z_mm >= z0 && p.z_mm <= z1 {
                    println!("track {} line {} row {:?} x {:.0} z {:.0} h {:.1} q {} sig {:.2}", t.id, t.line, t.observed_row, p.x_mm, p.z_mm, p.h_mm, p.quality, p.h_sigma_mm);
                }
            }
        }
    }).unwrap();
}
