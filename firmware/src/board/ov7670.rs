//! OV7670 registers and the set-up table for Flatland: YUV422 (the board
//! keeps only Y), the whole VGA array (the board bins it 2x2), no scaler,
//! slow pixel clock.
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
/// VGA, YUV (COM7[2]=0, COM7[0]=0).
pub const COM7_VGA_YUV: u8 = 0x00;
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

/// The VGA window the Linux driver uses (OmniVision's values; the
/// horizontal counter wraps at 784, hence stop < start).
pub const VGA_HSTART: u16 = 158;
pub const VGA_VSTART: u16 = 10;
pub const VGA_WIDTH: u16 = 640;
pub const VGA_HEIGHT: u16 = 480;
const H_WRAP: u16 = 784;

/// The output window, in sensor pixels/lines relative to the VGA window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    /// Offset of the first output column in the VGA image.
    pub left: u16,
    /// Offset of the first output row in the VGA image.
    pub top: u16,
    pub width: u16,
    pub height: u16,
}

/// The whole VGA array: the board bins it 2x2 to 320x240 (QVGA field of
/// view, no sensor scaler involved). A smaller window (a crop: fx, fy stay,
/// cx, cy shift by `left`, `top`) costs field of view.
pub const WINDOW_VGA: Window = Window { left: 0, top: 0, width: VGA_WIDTH, height: VGA_HEIGHT };

/// HSTART, HSTOP, HREF, VSTRT, VSTOP, VREF for `window` (11-bit horizontal,
/// 10-bit vertical counters split across registers; HREF keeps OmniVision's
/// edge offset 0b10 in bits 7:6, VREF's AGC bits 7:4 stay 0).
pub const fn window_registers(window: Window) -> [(u8, u8); 6] {
    let hstart = (VGA_HSTART + window.left) % H_WRAP;
    let hstop = (VGA_HSTART + window.left + window.width) % H_WRAP;
    let vstart = VGA_VSTART + window.top;
    let vstop = vstart + window.height;
    [
        (HSTART, (hstart >> 3) as u8),
        (HSTOP, (hstop >> 3) as u8),
        (HREF, 0x80 | (((hstop & 7) as u8) << 3) | (hstart & 7) as u8),
        (VSTRT, (vstart >> 2) as u8),
        (VSTOP, (vstop >> 2) as u8),
        (VREF, (((vstop & 3) as u8) << 2) | (vstart & 3) as u8),
    ]
}

/// CLKRC prescaler: PCLK = XCLK / (n + 1). With XCLK = 16 MHz (HSI on MCO1)
/// and n = 2, PCLK = 5.33 MHz: a VGA line every 294 us, so one binned output
/// row per 588 us (98,800 CPU cycles at 168 MHz, >10x the remap's per-row
/// cost), 6.7 frames/s. Raise the rate (smaller n) only once the whole
/// per-row pipeline is measured on the board.
pub const CLKRC_DIVIDER: u8 = 2;

/// Register writes after the soft reset (COM7_RESET, then >= 1 ms).
/// The window comes from [`window_registers`], written right after.
pub const SETUP: &[(u8, u8)] = &[
    (CLKRC, CLKRC_DIVIDER),
    // PLL bypassed: the prescaler alone sets PCLK.
    (DBLV, 0x0A),
    (COM7, COM7_VGA_YUV),
    (TSLB, TSLB_YUYV),
    (COM13, COM13_GAMMA | COM13_UVSAT),
    (COM15, COM15_R00FF),
    (RGB444, 0x00),
    (COM1, 0x00),
    // No scaler, no DCW, no PCLK divider: the window is a crop.
    (COM3, 0x00),
    (COM14, 0x00),
    (SCALING_XSC, 0x3A),
    (SCALING_YSC, 0x35),
    (SCALING_DCWCTR, 0x11),
    (SCALING_PCLK_DIV, 0xF0),
    (SCALING_PCLK_DELAY, 0x02),
    // HREF (not HSYNC), VSYNC active high, PCLK free-running: what DCMI expects.
    (COM10, 0x00),
    // AEC/AGC: limits first, enables last (OmniVision's order).
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
    (COM11, 0x12),
];

// Checked at compile time (the firmware has no host tests): the formula
// reproduces the Linux driver's VGA registers HSTART 0x13, HSTOP 0x01,
// HREF 0xB6, VSTRT 0x02, VSTOP 0x7A, VREF 0x0A.
const _: () = {
    let vga = window_registers(WINDOW_VGA);
    let expected = [0x13, 0x01, 0xB6, 0x02, 0x7A, 0x0A];
    let mut i = 0;
    while i < 6 {
        assert!(vga[i].1 == expected[i]);
        i += 1;
    }
};
