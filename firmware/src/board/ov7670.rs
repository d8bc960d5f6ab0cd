//! OV7670 registers and the set-up table for Flatland: QVGA (320x240)
//! YUV422 at 30 frames/s (the board keeps only Y). QVGA comes from the
//! whole VGA array downsampled 2x2 by the sensor's DCW block (COM3/COM14/
//! SCALING_*, OmniVision's implementation-guide route), not from COM7's
//! QVGA preset, so the field of view stays the VGA one and the pixel clock
//! divider is explicit.
//!
//! Only the registers the set-up writes or reads are named; the names follow
//! the OmniVision OV7670/OV7171 datasheet (v1.4). The
//! "reserved" tuning values are the OmniVision reference values that the
//! Linux `ov7670` driver also writes; they are undocumented, so they keep
//! their addresses.
//!
//! Pure data and `const fn`s: no HAL, so the table can be checked without
//! the board.

/// 7-bit SCCB address (0x42 write / 0x43 read on the wire).
pub const SCCB_ADDRESS: u8 = 0x21;
/// PID / VER read back before set-up (OV7670: 0x76, 0x73).
pub const PRODUCT_ID: (u8, u8) = (0x76, 0x73);

// Register addresses (datasheet names).
pub const GAIN: u8 = 0x00;
/// Vertical frame control: VSTART/VSTOP low bits, AGC high bits.
pub const VREF: u8 = 0x03;
pub const COM1: u8 = 0x04;
pub const PID: u8 = 0x0A;
pub const VER: u8 = 0x0B;
/// Output swap, scale and DCW (downsample/crop/window) enables.
pub const COM3: u8 = 0x0C;
pub const COM4: u8 = 0x0D;
pub const COM5: u8 = 0x0E;
pub const COM6: u8 = 0x0F;
pub const AECH: u8 = 0x10;
/// Internal clock prescaler.
pub const CLKRC: u8 = 0x11;
/// Reset, output format (resolution, YUV/RGB/Bayer).
pub const COM7: u8 = 0x12;
/// AGC / AEC / AWB enables.
pub const COM8: u8 = 0x13;
/// Automatic gain ceiling.
pub const COM9: u8 = 0x14;
/// HREF/HSYNC, VSYNC and PCLK polarity.
pub const COM10: u8 = 0x15;
/// Output window horizontal start, high 8 bits (low 3 in HREF).
pub const HSTART: u8 = 0x17;
/// Output window horizontal stop, high 8 bits (low 3 in HREF).
pub const HSTOP: u8 = 0x18;
/// Output window vertical start, high 8 bits (low 2 in VREF).
pub const VSTRT: u8 = 0x19;
/// Output window vertical stop, high 8 bits (low 2 in VREF).
pub const VSTOP: u8 = 0x1A;
pub const MVFP: u8 = 0x1E;
pub const AEW: u8 = 0x24;
pub const AEB: u8 = 0x25;
pub const VPT: u8 = 0x26;
/// HREF control: edge offset, HSTOP / HSTART low bits.
pub const HREF: u8 = 0x32;
/// Line buffer test option: YUV output sequence (with COM13[0]).
pub const TSLB: u8 = 0x3A;
pub const COM11: u8 = 0x3B;
pub const COM12: u8 = 0x3C;
/// Gamma, UV saturation, UV swap.
pub const COM13: u8 = 0x3D;
/// PCLK divider and manual scaling enable.
pub const COM14: u8 = 0x3E;
pub const EDGE: u8 = 0x3F;
/// Output data range, RGB 555/565.
pub const COM15: u8 = 0x40;
pub const COM16: u8 = 0x41;
pub const GFIX: u8 = 0x69;
/// PLL control (input clock multiplier).
pub const DBLV: u8 = 0x6B;
pub const SCALING_XSC: u8 = 0x70;
pub const SCALING_YSC: u8 = 0x71;
pub const SCALING_DCWCTR: u8 = 0x72;
pub const SCALING_PCLK_DIV: u8 = 0x73;
pub const RGB444: u8 = 0x8C;
pub const HAECC1: u8 = 0x9F;
pub const HAECC2: u8 = 0xA0;
pub const SCALING_PCLK_DELAY: u8 = 0xA2;
pub const BD50MAX: u8 = 0xA5;
pub const HAECC3: u8 = 0xA6;
pub const HAECC4: u8 = 0xA7;
pub const HAECC5: u8 = 0xA8;
pub const HAECC6: u8 = 0xA9;
pub const HAECC7: u8 = 0xAA;
pub const BD60MAX: u8 = 0xAB;

// Bit values.
pub const COM7_RESET: u8 = 0x80;
/// VGA, YUV (COM7[2]=0, COM7[0]=0): the sensor's timing stays VGA's, the
/// DCW block makes QVGA of it.
pub const COM7_VGA_YUV: u8 = 0x00;
/// COM3[2]: downsample/crop/window (DCW) enable.
pub const COM3_DCW_EN: u8 = 0x04;
/// COM14[4]: PCLK from the DCW/scaler divider (bits 2:0 and
/// SCALING_PCLK_DIV); COM14[3]: manual scaling (the DCW settings below,
/// not a preset).
pub const COM14_DCW_PCLK: u8 = 0x10;
pub const COM14_MANUAL_SCALING: u8 = 0x08;
/// PCLK divider code for /2 (COM14[2:0] and SCALING_PCLK_DIV[2:0]).
pub const PCLK_DIV_2: u8 = 0x01;
/// SCALING_DCWCTR: downsample by 2 vertically (bits 5:4) and horizontally (bits 1:0).
pub const DCWCTR_DOWNSAMPLE_2: u8 = 0x11;
/// SCALING_PCLK_DIV: bits 7:4 as OmniVision's tables write them.
pub const SCALING_PCLK_DIV_BASE: u8 = 0xF0;
/// DBLV[7:6]: PLL x6 (00 bypass, 01 x4, 10 x6, 11 x8); bits 3:0 keep
/// their reset value 0xA, bit 4 = 0 keeps the internal regulator.
pub const DBLV_PLL_X6: u8 = 0x80;
pub const DBLV_RESERVED: u8 = 0x0A;
pub const COM8_FASTAEC: u8 = 0x80;
pub const COM8_AECSTEP: u8 = 0x40;
pub const COM8_BFILT: u8 = 0x20;
pub const COM8_AGC: u8 = 0x04;
pub const COM8_AEC: u8 = 0x01;
pub const COM13_GAMMA: u8 = 0x80;
pub const COM13_UVSAT: u8 = 0x40;
/// Full output range 00..FF.
pub const COM15_R00FF: u8 = 0xC0;
/// TSLB[3] = 0 with COM13[0] = 0: bytes come Y0 U0 Y1 V0.
pub const TSLB_YUYV: u8 = 0x04;

/// Where Y sits in each 2-byte YUYV pixel (0 with [`TSLB_YUYV`]).
pub const Y_OFFSET: usize = 0;

/// The output frame: the VGA array downsampled 2x2.
pub const QVGA_WIDTH: u16 = 320;
pub const QVGA_HEIGHT: u16 = 240;
/// The sensor's read-out window is always the whole 640x480 array.
const ARRAY_WIDTH: u16 = 640;
const ARRAY_HEIGHT: u16 = 480;
/// The horizontal counter wraps at 784 (a line is 784 pixel times), hence
/// stop < start; a frame is 510 lines (datasheet "VGA frame timing":
/// 3 VSYNC, 17 blank, 480 active, 10 blank).
const H_WRAP: u16 = 784;
pub const LINE_PIXEL_TIMES: u32 = H_WRAP as u32;
pub const FRAME_LINES: u32 = 510;

/// Where the 640x480 read-out window starts in the sensor's counters, and
/// HREF's edge offset (HREF[7:6]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    pub hstart: u16,
    pub vstart: u16,
    pub href_edge: u8,
}

/// The Linux driver's (OmniVision's) VGA window; only the compile-time
/// check below uses it, to pin [`window_registers`] to known values.
pub const WINDOW_VGA: Window = Window { hstart: 158, vstart: 10, href_edge: 0b10 };

/// The QVGA window: the DCW block delays the data against HREF, so the
/// window starts 16 pixel times later than VGA's, or the left columns are
/// blank. 174 and 10, edge offset 0, are values OV7670 QVGA drivers found
/// by trying (Adafruit_OV7670's table; LiveOV7670 starts at 174 too and
/// reports its first pixel and first few lines as garbage; ComputerNerd's
/// ov7670-no-ram starts at 180). A real board may want a few pixels either
/// way (docs/BOARD.md, what only the board can show).
pub const WINDOW_QVGA: Window = Window { hstart: 174, vstart: 10, href_edge: 0 };

/// HSTART, HSTOP, HREF, VSTRT, VSTOP, VREF for `window` over the whole
/// array (11-bit horizontal, 10-bit vertical counters split across
/// registers; VREF's AGC bits 7:4 stay 0).
pub const fn window_registers(window: Window) -> [(u8, u8); 6] {
    let hstart = window.hstart % H_WRAP;
    let hstop = (window.hstart + ARRAY_WIDTH) % H_WRAP;
    let vstart = window.vstart;
    let vstop = vstart + ARRAY_HEIGHT;
    [
        (HSTART, (hstart >> 3) as u8),
        (HSTOP, (hstop >> 3) as u8),
        (HREF, (window.href_edge << 6) | (((hstop & 7) as u8) << 3) | (hstart & 7) as u8),
        (VSTRT, (vstart >> 2) as u8),
        (VSTOP, (vstop >> 2) as u8),
        (VREF, (((vstop & 3) as u8) << 2) | (vstart & 3) as u8),
    ]
}

/// The sensor's internal clock: XCLK x PLL / (CLKRC[5:0] + 1). The array
/// is read out at VGA timing, two PCLK per pixel (YUV422), so 30 frames/s
/// need 784 x 510 x 2 x 30 = 24.0 MHz (OmniVision's 30 frames/s set-up is
/// a 24 MHz XCLK with the PLL bypassed). The board's XCLK is 16 MHz (HSI on
/// MCO1): PLL x6 = 96 MHz, / 4 = 24 MHz exactly, the pair Adafruit_OV7670's
/// rate search (PCLK = 0.8 MHz per frame/s, PLL 1/4/6/8, divider 1-32)
/// also picks for 16 MHz and 30 frames/s.
pub const PLL_MULTIPLIER: u32 = 6;
pub const CLKRC_DIVIDER: u8 = 3;

/// The internal clock for `xclk_hz`.
pub const fn internal_clock_hz(xclk_hz: u32) -> u32 {
    xclk_hz * PLL_MULTIPLIER / (CLKRC_DIVIDER as u32 + 1)
}

/// PCLK: the internal clock halved by the DCW divider (COM14, SCALING_PCLK_DIV),
/// as a QVGA line carries half a VGA line's bytes: 12 MHz at XCLK 16 MHz.
pub const fn pclk_hz(xclk_hz: u32) -> u32 {
    internal_clock_hz(xclk_hz) / 2
}

/// Frames per second x 1000 for `xclk_hz` (the timing is VGA's whatever
/// the output size: 784 x 510 pixel times of two internal clocks).
pub const fn frame_rate_millihertz(xclk_hz: u32) -> u32 {
    (internal_clock_hz(xclk_hz) as u64 * 1000 / (2 * LINE_PIXEL_TIMES * FRAME_LINES) as u64) as u32
}

/// Nanoseconds between two QVGA lines: the DCW block outputs one line per
/// two VGA line times (130.7 us at 30 frames/s).
pub const fn qvga_line_period_ns(xclk_hz: u32) -> u32 {
    (2 * 2 * LINE_PIXEL_TIMES as u64 * 1_000_000_000 / internal_clock_hz(xclk_hz) as u64) as u32
}

/// Register writes after the soft reset (COM7_RESET, then >= 1 ms).
/// The window comes from [`window_registers`], written right after.
pub const SETUP: &[(u8, u8)] = &[
    (CLKRC, CLKRC_DIVIDER),
    (DBLV, DBLV_PLL_X6 | DBLV_RESERVED),
    (COM7, COM7_VGA_YUV),
    (TSLB, TSLB_YUYV),
    (COM13, COM13_GAMMA | COM13_UVSAT),
    (COM15, COM15_R00FF),
    (RGB444, 0x00),
    (COM1, 0x00),
    // QVGA by DCW: downsample by 2 each way, PCLK / 2. The scaler proper
    // (COM3[3]) stays off, so XSC/YSC keep their reset values unused.
    (COM3, COM3_DCW_EN),
    (COM14, COM14_DCW_PCLK | COM14_MANUAL_SCALING | PCLK_DIV_2),
    (SCALING_XSC, 0x3A),
    (SCALING_YSC, 0x35),
    (SCALING_DCWCTR, DCWCTR_DOWNSAMPLE_2),
    (SCALING_PCLK_DIV, SCALING_PCLK_DIV_BASE | PCLK_DIV_2),
    (SCALING_PCLK_DELAY, 0x02),
    // HREF (not HSYNC), VSYNC active high, PCLK free-running: what DCMI expects.
    (COM10, 0x00),
    // AEC/AGC: limits first, enables last (OmniVision's order). The banding
    // filter's steps keep their reset values (BD50ST 0x99 = 153 lines,
    // BD60ST 0x7F = 127 lines: 10 ms and 8.3 ms at this 65.3 us VGA line).
    (COM8, COM8_FASTAEC | COM8_AECSTEP | COM8_BFILT),
    (GAIN, 0x00),
    (AECH, 0x00),
    (COM4, 0x40),
    (COM9, 0x18),
    (BD50MAX, 0x05),
    (BD60MAX, 0x07),
    (AEW, 0x95),
    (AEB, 0x33),
    (VPT, 0xE3),
    (HAECC1, 0x78),
    (HAECC2, 0x68),
    (0xA1, 0x03),
    (HAECC3, 0xD8),
    (HAECC4, 0xD8),
    (HAECC5, 0xF0),
    (HAECC6, 0x90),
    (HAECC7, 0x94),
    (COM8, COM8_FASTAEC | COM8_AECSTEP | COM8_BFILT | COM8_AGC | COM8_AEC),
    // OmniVision reference values (reserved registers, undocumented).
    (COM5, 0x61),
    (COM6, 0x4B),
    (0x16, 0x02),
    (MVFP, 0x07),
    (0x21, 0x02),
    (0x22, 0x91),
    (0x29, 0x07),
    (0x33, 0x0B),
    (0x35, 0x0B),
    (0x37, 0x1D),
    (0x38, 0x71),
    (0x39, 0x2A),
    (COM12, 0x78),
    (0x4D, 0x40),
    (0x4E, 0x20),
    (GFIX, 0x00),
    (0x74, 0x10),
    (0x8D, 0x4F),
    (0x8E, 0x00),
    (0x8F, 0x00),
    (0x90, 0x00),
    (0x91, 0x00),
    (0x96, 0x00),
    (0x9A, 0x00),
    (0xB0, 0x84),
    (0xB1, 0x0C),
    (0xB2, 0x0E),
    (0xB3, 0x82),
    (0xB8, 0x0A),
    (COM16, 0x08),
    (EDGE, 0x00),
    // No night mode (it would stretch frames in the dark), 50/60 Hz
    // banding detected automatically.
    (COM11, 0x12),
];

// Checked at compile time (the firmware has no host tests).
const _: () = {
    // The formula reproduces the Linux driver's VGA registers HSTART 0x13,
    // HSTOP 0x01, HREF 0xB6, VSTRT 0x02, VSTOP 0x7A, VREF 0x0A ...
    let vga = window_registers(WINDOW_VGA);
    let expected = [0x13, 0x01, 0xB6, 0x02, 0x7A, 0x0A];
    let mut i = 0;
    while i < 6 {
        assert!(vga[i].1 == expected[i]);
        i += 1;
    }
    // ... and the QVGA window's vertical registers are those of the
    // published QVGA tables (VSTRT 0x02, VSTOP 0x7A, VREF 0x0A).
    let qvga = window_registers(WINDOW_QVGA);
    assert!(qvga[0].1 == 0x15 && qvga[1].1 == 0x03 && qvga[2].1 == 0x36);
    assert!(qvga[3].1 == 0x02 && qvga[4].1 == 0x7A && qvga[5].1 == 0x0A);
    // 16 MHz XCLK: 24 MHz inside, PCLK 12 MHz, 30.0 frames/s, a QVGA line
    // every 130.7 us.
    assert!(internal_clock_hz(16_000_000) == 24_000_000);
    assert!(pclk_hz(16_000_000) == 12_000_000);
    assert!(frame_rate_millihertz(16_000_000) == 30_012);
    assert!(qvga_line_period_ns(16_000_000) == 130_666);
    // The downsampling halves the whole array.
    assert!(ARRAY_WIDTH / 2 == QVGA_WIDTH && ARRAY_HEIGHT / 2 == QVGA_HEIGHT);
};
