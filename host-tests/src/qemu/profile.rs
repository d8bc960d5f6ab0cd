//! Where the firmware's instructions go, per function, from QEMU's own
//! record of what it ran (`-d in_asm,exec,nochain`): each translated block
//! is listed once with its instructions, and each execution of a block by
//! its address and function. `cargo fw-bench RECORDING --profile`.
//!
//! Counted: every instruction the emulated M4 ran, set-up and serial
//! waits included, up to the kernel benchmarks that follow the frames.
//! The library routines the M4 has no instruction for (soft `f64`,
//! 64-bit conversions, libm, memset/memcpy) are charged to the function
//! that called them as well, since that is where a change would go.

use std::collections::HashMap;
use std::io::{self, BufRead};

/// QEMU's arguments that write the record to `path`.
pub fn qemu_args(path: &std::path::Path) -> [std::ffi::OsString; 4] {
    ["-d".into(), "in_asm,exec,nochain".into(), "-D".into(), path.as_os_str().to_owned()]
}

/// The first function of the firmware's kernel benchmarks: the record is
/// read up to it.
const STOP_AT: &str = "kernel_bench";

/// Instructions per function, and per library routine with its caller.
#[derive(Debug, Default)]
pub struct Profile {
    pub total: u64,
    /// Function -> instructions run in its own blocks.
    pub functions: Vec<(String, u64)>,
    /// (routine, caller) -> instructions run in the routine for that caller.
    pub routines: Vec<((String, String), u64)>,
    /// (block address, function) -> instructions run in that block: the
    /// hot loops, to read in the disassembly (`llvm-objdump -d`).
    pub blocks: Vec<((u32, String), u64)>,
}

/// Whether `name` is a library routine charged to its caller.
fn is_routine(name: &str) -> bool {
    name.starts_with("__aeabi") || name.contains("compiler_builtins") || name.contains("libm") || name == "fminf" || name == "fmaxf"
}

/// Where a profile starts counting: at the `nth` (1-based) entry of
/// `function` (demangled, without its hash). A function is entered at the
/// start of its first translated block: the record lists a block before it
/// runs, and nothing runs a function's middle before its entry.
pub struct Start<'a> {
    pub function: &'a str,
    pub nth: usize,
}

/// Reads QEMU's record (`qemu_args`' file), counting from `start` (None:
/// from the first instruction).
pub fn read(record: impl BufRead, start: Option<Start>) -> io::Result<Profile> {
    // The entry address of `start`'s function, once listed; its entries so far.
    let (mut entry, mut listing_entry, mut entries) = (None, false, 0);
    // A block's instructions by its translation, named by the host code
    // QEMU made of it: one address can have several at once (under
    // -icount a block that touches a peripheral is translated again, one
    // instruction long, for that access). A listed block runs next, so the
    // next run at its address names its translation. `latest`: each
    // address's last listed count, for a run whose translation was not seen.
    let (mut listed, mut latest): (HashMap<u32, u64>, HashMap<u32, u64>) = (HashMap::new(), HashMap::new());
    let mut translations: HashMap<u64, u64> = HashMap::new();
    let mut open: Option<(u32, u64)> = None;
    let mut functions: HashMap<String, u64> = HashMap::new();
    let mut routines: HashMap<(String, String), u64> = HashMap::new();
    let mut runs: HashMap<(u32, String), u64> = HashMap::new();
    let mut caller = String::new();
    let mut total = 0;
    for line in record.lines() {
        let line = line?;
        if let Some(address) = line.strip_prefix("0x") {
            // "0x08000404:  4812  ldr ...": an instruction of the block being listed.
            let Some(address) = address.split(':').next().and_then(|a| u32::from_str_radix(a, 16).ok()) else { continue };
            let block = open.get_or_insert((address, 0));
            block.1 += 1;
            if std::mem::take(&mut listing_entry) {
                entry = Some(address);
            }
            continue;
        }
        if let Some((start, count)) = open.take() {
            listed.insert(start, count);
            latest.insert(start, count);
        }
        if let (Some(name), Some(start), None) = (line.strip_prefix("IN: "), &start, entry) {
            listing_entry = demangled(name.trim()) == start.function;
            continue;
        }
        // "Trace 0: 0x7f.. [00800408/08000400/00000110/ff020200] Reset"
        let Some(rest) = line.strip_prefix("Trace ") else { continue };
        let Some((head, (fields, name))) = rest.split_once('[').and_then(|(head, r)| Some((head, r.split_once(']')?))) else { continue };
        let Some(pc) = fields.split('/').nth(1).and_then(|pc| u32::from_str_radix(pc, 16).ok()) else { continue };
        let host = head.split_whitespace().last().and_then(|h| u64::from_str_radix(h.trim_start_matches("0x"), 16).ok());
        let count = match (host, listed.remove(&pc)) {
            (Some(host), Some(count)) => *translations.entry(host).insert_entry(count).get(),
            (Some(host), None) => translations.get(&host).or(latest.get(&pc)).copied().unwrap_or(0),
            (None, _) => latest.get(&pc).copied().unwrap_or(0),
        };
        let name = name.trim();
        if name.contains(STOP_AT) {
            break;
        }
        if let Some(start) = &start {
            entries += usize::from(entry == Some(pc));
            if entries < start.nth {
                continue;
            }
        }
        total += count;
        // Demangled once: the record has a line per block run.
        let function = demangled(name);
        *functions.entry(function.clone()).or_default() += count;
        *runs.entry((pc, function.clone())).or_default() += count;
        if is_routine(name) {
            *routines.entry((function, caller.clone())).or_default() += count;
        } else if !name.is_empty() {
            caller = function;
        }
    }
    Ok(Profile { total, functions: sorted(functions), routines: sorted(routines), blocks: sorted(runs) })
}

/// Most instructions first (ties by name, so the order is the same every run).
fn sorted<K: Ord>(map: HashMap<K, u64>) -> Vec<(K, u64)> {
    let mut entries: Vec<_> = map.into_iter().collect();
    entries.sort_by(|a, b| b.1.cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    entries
}

/// A symbol as source names it, without its hash.
fn demangled(name: &str) -> String {
    format!("{:#}", rustc_demangle::demangle(name))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn blocks_are_counted_per_run_and_routines_per_caller() {
        let record = "\
----------------
IN: main
0x08000100:  4812       ldr      r0, [pc, #0x48]
0x08000102:  f000 f801  bl       #0x8000108

Trace 0: 0x7f00 [00800408/08000100/00000110/ff020200] main
----------------
IN: __aeabi_dmul
0x08000108:  b580       push     {r7, lr}
0x0800010a:  bd80       pop      {r7, pc}

Trace 0: 0x7f10 [00800408/08000108/00000110/ff020200] __aeabi_dmul
Trace 0: 0x7f00 [00800408/08000100/00000110/ff020200] main
Trace 0: 0x7f10 [00800408/08000108/00000110/ff020200] __aeabi_dmul
Trace 0: 0x7f20 [00800408/08000200/00000110/ff020200] kernel_bench
Trace 0: 0x7f00 [00800408/08000100/00000110/ff020200] main
";
        let profile = read(record.as_bytes(), None).unwrap();
        assert_eq!(profile.total, 8);
        assert_eq!(profile.functions, vec![("__aeabi_dmul".to_string(), 4), ("main".to_string(), 4)]);
        assert_eq!(profile.routines, vec![(("__aeabi_dmul".to_string(), "main".to_string()), 4)]);
        assert_eq!(profile.blocks, vec![((0x0800_0100, "main".to_string()), 4), ((0x0800_0108, "__aeabi_dmul".to_string()), 4)]);
        // From the second entry of __aeabi_dmul on: that run only, as
        // kernel_bench ends the record.
        let profile = read(record.as_bytes(), Some(Start { function: "__aeabi_dmul", nth: 2 })).unwrap();
        assert_eq!(profile.total, 2);
        assert_eq!(profile.functions, vec![("__aeabi_dmul".to_string(), 2)]);
    }

    #[test]
    fn a_block_translated_again_keeps_each_translation_apart() {
        // main's block, then a one-instruction translation of its start
        // (as -icount makes for a peripheral access), then both run again.
        let record = "\
IN: main
0x08000100:  4812       ldr      r0, [pc, #0x48]
0x08000102:  6800       ldr      r0, [r0]

Trace 0: 0x7f00 [00800408/08000100/00000110/ff020200] main
IN: main
0x08000100:  4812       ldr      r0, [pc, #0x48]

Trace 0: 0x7f80 [00800408/08000100/00000110/ff020200] main
Trace 0: 0x7f00 [00800408/08000100/00000110/ff020200] main
Trace 0: 0x7f80 [00800408/08000100/00000110/ff020200] main
";
        assert_eq!(read(record.as_bytes(), None).unwrap().total, 2 + 1 + 2 + 1);
    }
}
