//! Small helpers shared by the readers and writers: size-capped input,
//! atomic file output, bounded messages.

use std::io::{Read, Write};
use std::path::Path;

/// Writes `bytes` to `path` through a temporary file in the same folder and a
/// rename, so readers never see a half-written file and a failure leaves any
/// previous file intact.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    let file_name = path
        .file_name()
        .ok_or_else(|| std::io::Error::new(std::io::ErrorKind::InvalidInput, "no file name"))?;
    let tmp = dir.join(format!(
        ".{}.tmp{}",
        file_name.to_string_lossy(),
        std::process::id()
    ));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}
/// Reads at most `max_bytes` of `path`; a longer file (or an endless one,
/// such as `/dev/zero`) is an `InvalidData` error naming the cap, so a
/// wrong path cannot exhaust memory.
pub fn read_capped(path: &Path, max_bytes: u64) -> std::io::Result<Vec<u8>> {
    let mut bytes = Vec::new();
    std::fs::File::open(path)?
        .take(max_bytes + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(std::io::Error::new(
            std::io::ErrorKind::InvalidData,
            format!(
                "larger than {} MiB, the most this file can be",
                max_bytes >> 20
            ),
        ));
    }
    Ok(bytes)
}

/// `text` cut to at most `max_chars` characters, with the number left out,
/// so that a message quoting user input stays a line.
pub fn bounded(text: &str, max_chars: usize) -> String {
    let n = text.chars().count();
    if n <= max_chars {
        return text.to_string();
    }
    let kept: String = text.chars().take(max_chars).collect();
    format!("{kept}… ({} more characters)", n - max_chars)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bounded_keeps_short_text_and_counts_what_it_cuts() {
        assert_eq!(bounded("abc", 3), "abc");
        assert_eq!(bounded("äbcdé", 2), "äb… (3 more characters)");
    }

    #[test]
    fn read_capped_reads_up_to_the_cap_and_refuses_past_it() {
        let dir = tempfile::tempdir().expect("tempdir");
        let p = dir.path().join("f");
        std::fs::write(&p, [7u8; 10]).expect("write");
        assert_eq!(read_capped(&p, 10).expect("at the cap"), vec![7u8; 10]);
        let e = read_capped(&p, 9).expect_err("past the cap");
        assert_eq!(e.kind(), std::io::ErrorKind::InvalidData);
        let e = read_capped(Path::new("/dev/zero"), 1 << 20).expect_err("endless");
        assert!(e.to_string().contains("larger than 1 MiB"), "{e}");
    }
}
