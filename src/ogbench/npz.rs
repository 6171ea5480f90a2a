//! numpy's `.npz` files (`np.savez`, `np.savez_compressed`): a zip archive of `.npy` arrays.
//!
//! An `.npy` member is a magic string, a format version, a header (a Python dict literal with the
//! dtype `descr`, `fortran_order` and `shape`) and the array's bytes in C order. Only that much of
//! the format is read, and only little-endian numbers and booleans: what OGBench's files hold. The
//! header is parsed as data, never evaluated. Members are streamed: a reader gets the bytes after
//! the header as they decompress, so a dataset of gigabytes is read a window at a time, and two
//! members (observations and actions) are read side by side through two opens of the archive.

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::Path;

use anyhow::{Context, Result, bail};

/// The element types pgser reads and writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dtype {
    Bool,
    F32,
    F64,
    I32,
    I64,
}

impl Dtype {
    pub fn size(self) -> usize {
        match self {
            Dtype::Bool => 1,
            Dtype::F32 | Dtype::I32 => 4,
            Dtype::F64 | Dtype::I64 => 8,
        }
    }

    fn descr(self) -> &'static str {
        match self {
            Dtype::Bool => "|b1",
            Dtype::F32 => "<f4",
            Dtype::F64 => "<f8",
            Dtype::I32 => "<i4",
            Dtype::I64 => "<i8",
        }
    }

    fn parse(descr: &str) -> Option<Dtype> {
        Some(match descr {
            "|b1" | "<b1" | "?" => Dtype::Bool,
            "<f4" => Dtype::F32,
            "<f8" => Dtype::F64,
            "<i4" => Dtype::I32,
            "<i8" => Dtype::I64,
            _ => return None,
        })
    }
}

/// One array of an archive, as its header describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    /// The key `np.load` gives it (the member's file name without `.npy`).
    pub key: String,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
}

impl Member {
    /// Rows (the first dimension; 1 for a 0-d array) and values per row.
    pub fn rows(&self) -> usize {
        self.shape.first().copied().unwrap_or(1)
    }

    pub fn row_len(&self) -> usize {
        self.shape.iter().skip(1).product()
    }

    pub fn bytes(&self) -> u64 {
        self.shape.iter().map(|&d| d as u64).product::<u64>() * self.dtype.size() as u64
    }
}

const MAGIC: &[u8] = b"\x93NUMPY";

fn archive(path: &Path) -> Result<zip::ZipArchive<BufReader<File>>> {
    let file = crate::output::open_input(path)?;
    zip::ZipArchive::new(BufReader::new(file))
        .with_context(|| format!("{}: not a .npz file (not a zip archive)", path.display()))
}

/// The arrays of the archive at `path`, in archive order, each header read and checked.
pub fn members(path: &Path) -> Result<Vec<Member>> {
    let mut z = archive(path)?;
    let mut out = Vec::new();
    for i in 0..z.len() {
        let mut f = z.by_index(i).with_context(|| format!("{}: member {i} cannot be read", path.display()))?;
        let Some(key) = f.name().strip_suffix(".npy").map(str::to_string) else { continue };
        let m = header(&mut f, &key).with_context(|| format!("{}: {key}", path.display()))?;
        let have = f.size();
        let want = m.bytes();
        // The member's size is its header and its data; a shorter one was cut short.
        if have < want {
            bail!(
                "{}: {key}: {have} bytes, less than the {want} bytes of its {:?} {:?} array",
                path.display(),
                m.shape,
                m.dtype
            );
        }
        out.push(m);
    }
    Ok(out)
}

/// Calls `f` with a reader of member `key`'s data (the bytes after its header) and its header.
pub fn with_member<T>(path: &Path, key: &str, f: impl FnOnce(&mut dyn Read, &Member) -> Result<T>) -> Result<T> {
    let mut z = archive(path)?;
    let mut file = z
        .by_name(&format!("{key}.npy"))
        .with_context(|| format!("{}: no array {key:?} in the archive", path.display()))?;
    let m = header(&mut file, key).with_context(|| format!("{}: {key}", path.display()))?;
    f(&mut file, &m)
}

/// Reads and parses an `.npy` header, leaving `r` at the first data byte.
fn header(r: &mut dyn Read, key: &str) -> Result<Member> {
    let mut start = [0u8; 8];
    r.read_exact(&mut start).context("too short for an .npy header")?;
    if &start[..6] != MAGIC {
        bail!("not an .npy array (no \\x93NUMPY magic)");
    }
    let len = match start[6] {
        1 => {
            let mut b = [0u8; 2];
            r.read_exact(&mut b)?;
            u16::from_le_bytes(b) as usize
        }
        2 | 3 => {
            let mut b = [0u8; 4];
            r.read_exact(&mut b)?;
            u32::from_le_bytes(b) as usize
        }
        v => bail!(".npy format version {v}.{}: pgser reads versions 1 to 3", start[7]),
    };
    if len > 1 << 20 {
        bail!(".npy header of {len} bytes: corrupt");
    }
    let mut text = vec![0u8; len];
    r.read_exact(&mut text).context("the .npy header is cut short")?;
    let text = String::from_utf8_lossy(&text);
    let field = |name: &str| -> Result<&str> {
        let at = text.find(&format!("'{name}':")).with_context(|| format!("the header has no '{name}': {text}"))?;
        Ok(text[at + name.len() + 3..].trim_start())
    };
    let descr = field("descr")?;
    let descr = descr.strip_prefix('\'').and_then(|d| d.split('\'').next()).context("'descr' is not a string")?;
    let dtype = Dtype::parse(descr)
        .with_context(|| format!("dtype {descr:?}: pgser reads little-endian float32/64, int32/64 and bool arrays"))?;
    if field("fortran_order")?.starts_with("True") {
        bail!("a Fortran-order array: pgser reads C order (what np.save writes by default)");
    }
    let shape = field("shape")?;
    let inner = shape.strip_prefix('(').and_then(|s| s.split(')').next()).context("'shape' is not a tuple")?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>().with_context(|| format!("shape entry {s:?}")))
        .collect::<Result<Vec<_>>>()?;
    Ok(Member { key: key.to_string(), dtype, shape })
}

/// Writes an `.npz` archive one array at a time, each streamed in: `np.load` reads it, and with
/// `compressed` it is what `np.savez_compressed` writes (deflate), else `np.savez` (stored).
pub struct NpzWriter<W: Write + std::io::Seek> {
    zip: zip::ZipWriter<W>,
    compressed: bool,
    /// The array being written: its key and the bytes still expected.
    open: Option<(String, u64)>,
}

impl<W: Write + std::io::Seek> NpzWriter<W> {
    pub fn new(w: W, compressed: bool) -> NpzWriter<W> {
        NpzWriter { zip: zip::ZipWriter::new(w), compressed, open: None }
    }

    /// Starts array `key` of `dtype` and `shape`; its bytes follow through [`NpzWriter::write`].
    pub fn start(&mut self, key: &str, dtype: Dtype, shape: &[usize]) -> Result<()> {
        self.check_closed()?;
        let method = if self.compressed { zip::CompressionMethod::Deflated } else { zip::CompressionMethod::Stored };
        let bytes = shape.iter().map(|&d| d as u64).product::<u64>() * dtype.size() as u64;
        let opts = zip::write::FileOptions::default()
            .compression_method(method)
            .large_file(bytes > u32::MAX as u64 / 2)
            .last_modified_time(zip::DateTime::default());
        self.zip.start_file(format!("{key}.npy"), opts)?;
        // np.lib.format's version 1.0 header: the dict padded with spaces to a multiple of 64.
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        let tuple = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
        let mut dict = format!("{{'descr': '{}', 'fortran_order': False, 'shape': {tuple}, }}", dtype.descr());
        let total = MAGIC.len() + 2 + 2 + dict.len() + 1;
        dict.push_str(&" ".repeat(total.next_multiple_of(64) - total));
        dict.push('\n');
        self.zip.write_all(MAGIC)?;
        self.zip.write_all(&[1, 0])?;
        self.zip.write_all(&(dict.len() as u16).to_le_bytes())?;
        self.zip.write_all(dict.as_bytes())?;
        self.open = Some((key.to_string(), bytes));
        Ok(())
    }

    /// More bytes of the array started last.
    pub fn write(&mut self, data: &[u8]) -> Result<()> {
        let Some((key, left)) = &mut self.open else { bail!("no array started") };
        if data.len() as u64 > *left {
            bail!("{key}: more bytes than its shape holds");
        }
        *left -= data.len() as u64;
        self.zip.write_all(data)?;
        Ok(())
    }

    fn check_closed(&mut self) -> Result<()> {
        match self.open.take() {
            Some((key, left)) if left > 0 => bail!("{key}: {left} bytes short of its shape"),
            _ => Ok(()),
        }
    }

    /// Ends the archive; the writer is returned for the caller to commit.
    pub fn finish(mut self) -> Result<W> {
        self.check_closed()?;
        Ok(self.zip.finish()?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What this writer writes, this reader reads: keys, dtypes, shapes and bytes.
    #[test]
    fn a_written_archive_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        for compressed in [false, true] {
            let path = dir.path().join(format!("a{compressed}.npz"));
            let mut w = NpzWriter::new(File::create(&path).unwrap(), compressed);
            let x: Vec<u8> = (0..12).flat_map(|i| (i as f32 * 0.5).to_le_bytes()).collect();
            w.start("observations", Dtype::F32, &[4, 3]).unwrap();
            w.write(&x[..20]).unwrap();
            w.write(&x[20..]).unwrap();
            w.start("terminals", Dtype::Bool, &[4]).unwrap();
            w.write(&[0, 1, 0, 1]).unwrap();
            w.finish().unwrap();
            let m = members(&path).unwrap();
            assert_eq!(m[0], Member { key: "observations".into(), dtype: Dtype::F32, shape: vec![4, 3] });
            assert_eq!((m[1].key.as_str(), m[1].dtype, m[1].rows(), m[1].row_len()), ("terminals", Dtype::Bool, 4, 1));
            let got = with_member(&path, "observations", |r, _| {
                let mut b = Vec::new();
                r.read_to_end(&mut b)?;
                Ok(b)
            })
            .unwrap();
            assert_eq!(got, x);
            let e = with_member(&path, "actions", |_, _| Ok(())).unwrap_err();
            assert!(format!("{e:#}").contains("no array \"actions\""), "{e:#}");
        }
    }

    #[test]
    fn a_short_array_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("short.npz");
        let mut w = NpzWriter::new(File::create(&path).unwrap(), false);
        w.start("x", Dtype::F64, &[2]).unwrap();
        w.write(&[0; 8]).unwrap();
        assert!(w.finish().unwrap_err().to_string().contains("8 bytes short"));
    }
}
