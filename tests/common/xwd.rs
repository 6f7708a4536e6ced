//! Screenshots of X windows for the window tests (tests/service and
//! tests/cli include this file): `xwd` output parsed to RGB.

/// Reads an XWD (X Window Dump) of a 24/32-bit TrueColor window as RGB;
/// `None` for a dump shorter than its header says (taken while the window
/// was mapping), which the caller retries.
fn parse_xwd(b: &[u8]) -> Option<(usize, usize, Vec<u8>)> {
    if b.len() < 100 {
        return None;
    }
    let be = |i: usize| u32::from_be_bytes([b[4 * i], b[4 * i + 1], b[4 * i + 2], b[4 * i + 3]]);
    let (header, w, h) = (be(0) as usize, be(4) as usize, be(5) as usize);
    let (byte_order, bpp, stride) = (be(7), be(11) as usize, be(12) as usize);
    let (rm, gm, bm, ncolors) = (be(14), be(15), be(16), be(19) as usize);
    assert_eq!(bpp, 32, "expected a 32-bit visual");
    let data = b.get(header + 12 * ncolors..)?;
    if h > 0 && data.len() < (h - 1) * stride + 4 * w {
        return None;
    }
    let chan = |p: u32, m: u32| ((p & m) >> m.trailing_zeros()) as u8;
    let mut rgb = Vec::with_capacity(3 * w * h);
    for y in 0..h {
        for x in 0..w {
            let q = &data[y * stride + 4 * x..y * stride + 4 * x + 4];
            let p = if byte_order == 0 {
                u32::from_le_bytes([q[0], q[1], q[2], q[3]])
            } else {
                u32::from_be_bytes([q[0], q[1], q[2], q[3]])
            };
            rgb.extend([chan(p, rm), chan(p, gm), chan(p, bm)]);
        }
    }
    Some((w, h, rgb))
}

/// A screenshot of the window named `name` (`xwd`, x11-apps), or why not
/// (an `xwd` that has not finished within 20 s, a fraction of the callers'
/// own deadlines for their retries, is killed). No `xwd` at all fails the
/// test.
pub fn screenshot(name: &str) -> Result<(usize, usize, Vec<u8>), String> {
    use super::deadline::CommandWithin;
    const XWD_WITHIN: std::time::Duration = std::time::Duration::from_secs(20);
    let shot = std::process::Command::new("xwd")
        .args(["-name", name, "-silent"])
        .try_output_within(XWD_WITHIN, "xwd (x11-apps)")
        .map_err(|o| {
            format!(
                "xwd did not finish within {XWD_WITHIN:?}: {}",
                String::from_utf8_lossy(&o.stderr)
            )
        })?;
    if shot.status.success() {
        parse_xwd(&shot.stdout).ok_or_else(|| "a truncated dump".to_string())
    } else {
        Err(String::from_utf8_lossy(&shot.stderr).into_owned())
    }
}
