//! numpy's `.npz` files (`np.savez`, `np.savez_compressed`): a zip archive of `.npy` arrays.
//!
//! An `.npy` member is a magic string, a format version, a header (a Python dict literal with the
//! dtype `descr`, `fortran_order` and `shape`) and the array's bytes. Only that much of the format
//! is read: numbers and booleans, in either byte order and either memory order, as `np.save`
//! writes them (OGBench's files are little-endian C order; a user's own `np.savez` of a
//! `.byteswap()`ed or `np.asfortranarray` array is not, and the pickle reader takes both too). The
//! header is parsed as data, never evaluated. Members are streamed: a reader gets the bytes after
//! the header as they decompress, little-endian and in C order, so a dataset of gigabytes is read
//! a window at a time, and several members (observations, actions and every member kept beside
//! them) are read side by side, each through an open of the archive of its own
//! ([`with_members`]). A big-endian member is byte-swapped as it streams; a Fortran-order
//! one is read whole and transposed, as `np.load` does: its rows' values lie a column apart, so no
//! window of the stream holds a row.

use std::fs::File;
use std::io::{BufReader, Cursor, Read, Write};
use std::path::Path;

use anyhow::{Context, Result, bail};

use crate::dtype::Dtype;

/// How a member's bytes lie in the file, where not as readers get them (little-endian, C order).
#[derive(Debug, Clone, Copy, Default)]
struct Storage {
    big_endian: bool,
    fortran: bool,
}

/// One array of an archive, as its header describes it.
#[derive(Debug, Clone, PartialEq)]
pub struct Member {
    /// The key `np.load` gives it (the member's file name without `.npy`).
    pub key: String,
    pub dtype: Dtype,
    pub shape: Vec<usize>,
    /// Whether the file stores it big-endian (readers get it little-endian all the same).
    pub stored_big_endian: bool,
}

impl Member {
    /// numpy's `descr` as the file stores it (`<f4`, `>f8`, `|b1`): what an export writes back.
    pub fn stored_descr(&self) -> String {
        self.stored_dtype().descr()
    }

    /// The dtype as the file stores it, byte order included.
    pub fn stored_dtype(&self) -> Dtype {
        self.dtype.with_big_endian(self.stored_big_endian)
    }

    /// Rows (the first dimension; 1 for a 0-d array) and values per row.
    pub fn rows(&self) -> usize {
        self.shape.first().copied().unwrap_or(1)
    }

    pub fn row_len(&self) -> usize {
        self.shape.iter().skip(1).product()
    }

    pub fn bytes(&self) -> u64 {
        self.shape.iter().map(|&d| d as u64).product::<u64>() * self.dtype.size as u64
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
        let (m, _) = header(&mut f, &key).with_context(|| format!("{}: {key}", path.display()))?;
        let have = f.size();
        let want = m.bytes();
        // The member's size is its header and its data; a shorter one was cut short.
        if have < want {
            bail!(
                "{}: {key}: {have} bytes, less than the {want} bytes of its {:?} {} array",
                path.display(),
                m.shape,
                m.dtype.name()
            );
        }
        out.push(m);
    }
    Ok(out)
}

/// Calls `f` with a reader of member `key`'s data (the bytes after its header, little-endian and
/// in C order whatever the file's) and its header.
pub fn with_member<T>(path: &Path, key: &str, f: impl FnOnce(&mut dyn Read, &Member) -> Result<T>) -> Result<T> {
    let mut z = archive(path)?;
    let mut file = z
        .by_name(&format!("{key}.npy"))
        .with_context(|| format!("{}: no array {key:?} in the archive", path.display()))?;
    let (m, storage) = header(&mut file, key).with_context(|| format!("{}: {key}", path.display()))?;
    let size = m.dtype.size;
    // The member's type as the file stores it: `reorder` turns its bytes little-endian.
    let stored = m.stored_dtype();
    // A Fortran array with one dimension above 1 has C order's bytes already.
    if storage.fortran && m.shape.iter().filter(|&&d| d > 1).count() > 1 {
        let mut raw = Vec::new();
        (&mut file).take(m.bytes()).read_to_end(&mut raw).with_context(|| format!("{}: {key}", path.display()))?;
        if raw.len() as u64 != m.bytes() {
            bail!(
                "{}: {key}: {} bytes, less than the {} bytes of its {:?} array",
                path.display(),
                raw.len(),
                m.bytes(),
                m.shape
            );
        }
        let mut c = crate::pickle::fortran_to_c(&raw, &m.shape, size);
        stored.reorder(&mut c);
        return f(&mut Cursor::new(c), &m);
    }
    if storage.big_endian {
        return f(&mut SwapBytes::new(&mut file, stored), &m);
    }
    f(&mut file, &m)
}

/// Calls `f` with a reader of each of `keys`' data, side by side (one open of the archive each,
/// so that several members stream at once): [`with_member`] for many. `open` holds the readers
/// opened so far (pass an empty vector).
pub fn with_members(
    path: &Path,
    keys: &[String],
    open: &mut Vec<&mut dyn Read>,
    f: &mut dyn FnMut(&mut [&mut dyn Read]) -> Result<()>,
) -> Result<()> {
    let Some((key, rest)) = keys.split_first() else { return f(open) };
    with_member(path, key, |r, _| {
        let mut next: Vec<&mut dyn Read> = open.iter_mut().map(|x| &mut **x as &mut dyn Read).collect();
        next.push(r);
        with_members(path, rest, &mut next, f)
    })
}

/// A reader of numbers stored as `stored` (big-endian) that hands them out little-endian, a
/// buffer of whole numbers at a time.
struct SwapBytes<R: Read> {
    inner: R,
    stored: Dtype,
    buf: Vec<u8>,
    at: usize,
    end: usize,
}

impl<R: Read> SwapBytes<R> {
    fn new(inner: R, stored: Dtype) -> SwapBytes<R> {
        let size = stored.size;
        SwapBytes { inner, stored, buf: vec![0; (64 << 10) / size * size], at: 0, end: 0 }
    }
}

impl<R: Read> Read for SwapBytes<R> {
    fn read(&mut self, out: &mut [u8]) -> std::io::Result<usize> {
        if self.at == self.end {
            // Fill the buffer as far as the stream goes, so that numbers are whole before a swap.
            let mut n = 0;
            while n < self.buf.len() {
                match self.inner.read(&mut self.buf[n..]) {
                    Ok(0) => break,
                    Ok(k) => n += k,
                    Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                    Err(e) => return Err(e),
                }
            }
            // A partial number at the end is a member cut short: handed out as it is, and the
            // caller's read_exact of whole rows fails on it.
            self.stored.reorder(&mut self.buf[..n - n % self.stored.size]);
            (self.at, self.end) = (0, n);
        }
        let k = out.len().min(self.end - self.at);
        out[..k].copy_from_slice(&self.buf[self.at..self.at + k]);
        self.at += k;
        Ok(k)
    }
}

/// Reads and parses an `.npy` header, leaving `r` at the first data byte.
fn header(r: &mut dyn Read, key: &str) -> Result<(Member, Storage)> {
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
    let stored = Dtype::parse(descr)
        .filter(|d| d.arrow().is_some())
        .with_context(|| format!("dtype {descr:?}: pgser reads bool, int, uint and float32/64 arrays"))?;
    let (dtype, big_endian) = (stored.little_endian(), stored.big_endian);
    let fortran = field("fortran_order")?.starts_with("True");
    let shape = field("shape")?;
    let inner = shape.strip_prefix('(').and_then(|s| s.split(')').next()).context("'shape' is not a tuple")?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.trim_end_matches('L').parse::<usize>().with_context(|| format!("shape entry {s:?}")))
        .collect::<Result<Vec<_>>>()?;
    Ok((Member { key: key.to_string(), dtype, shape, stored_big_endian: big_endian }, Storage { big_endian, fortran }))
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

    /// Starts array `key` of `dtype` and `shape`; its bytes follow through [`NpzWriter::write`],
    /// in `dtype`'s byte order (`>f8` for an array given back as its source stored it).
    pub fn start(&mut self, key: &str, dtype: Dtype, shape: &[usize]) -> Result<()> {
        let (descr, size) = (dtype.descr(), dtype.size);
        self.check_closed()?;
        let method = if self.compressed { zip::CompressionMethod::Deflated } else { zip::CompressionMethod::Stored };
        let bytes = shape.iter().map(|&d| d as u64).product::<u64>() * size as u64;
        let opts = zip::write::FileOptions::default()
            .compression_method(method)
            .large_file(bytes > u32::MAX as u64 / 2)
            .last_modified_time(zip::DateTime::default());
        self.zip.start_file(format!("{key}.npy"), opts)?;
        // np.lib.format's version 1.0 header: the dict padded with spaces to a multiple of 64.
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        let tuple = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
        let mut dict = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {tuple}, }}");
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
            w.start("terminals", Dtype::BOOL, &[4]).unwrap();
            w.write(&[0, 1, 0, 1]).unwrap();
            w.finish().unwrap();
            let m = members(&path).unwrap();
            let want =
                Member { key: "observations".into(), dtype: Dtype::F32, shape: vec![4, 3], stored_big_endian: false };
            assert_eq!(m[0], want);
            assert_eq!((m[1].key.as_str(), m[1].dtype, m[1].rows(), m[1].row_len()), ("terminals", Dtype::BOOL, 4, 1));
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

    /// An `.npy` member as `np.save` writes it, for any `descr` and memory order.
    fn raw_npy(descr: &str, fortran: bool, shape: &str, data: &[u8]) -> Vec<u8> {
        let order = if fortran { "True" } else { "False" };
        let mut dict = format!("{{'descr': '{descr}', 'fortran_order': {order}, 'shape': {shape}, }}");
        let total = MAGIC.len() + 4 + dict.len() + 1;
        dict.push_str(&" ".repeat(total.next_multiple_of(64) - total));
        dict.push('\n');
        let mut out = MAGIC.to_vec();
        out.extend([1, 0]);
        out.extend((dict.len() as u16).to_le_bytes());
        out.extend(dict.as_bytes());
        out.extend(data);
        out
    }

    fn read_all(path: &Path, key: &str) -> (Vec<u8>, Member) {
        with_member(path, key, |r, m| {
            let mut b = Vec::new();
            r.read_to_end(&mut b)?;
            Ok((b, m.clone()))
        })
        .unwrap()
    }

    /// Big-endian and Fortran-order members (`np.save` of `a.byteswap().view(a.dtype.newbyteorder())`
    /// and of `np.asfortranarray(a)`) read as the little-endian C-order array they hold.
    #[test]
    fn big_endian_and_fortran_members_read_as_c_order_little_endian() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("orders.npz");
        // a[i][j] = 10·i + j, shape (3, 4), as f32 and i64; the big f64 array spans several buffers.
        let a: Vec<f32> = (0..3).flat_map(|i| (0..4).map(move |j| (10 * i + j) as f32)).collect();
        let le: Vec<u8> = a.iter().flat_map(|x| x.to_le_bytes()).collect();
        let be: Vec<u8> = a.iter().flat_map(|x| x.to_be_bytes()).collect();
        let fortran = |v: &[f32], bytes: fn(f32) -> [u8; 4]| -> Vec<u8> {
            (0..4).flat_map(|j| (0..3).map(move |i| v[i * 4 + j])).flat_map(bytes).collect()
        };
        let ints: Vec<i64> = (0..12).map(|k| k * 1_000_000_007).collect();
        let ints_f: Vec<u8> =
            (0..4).flat_map(|j| (0..3).map(move |i| i * 4 + j)).flat_map(|k| ints[k].to_be_bytes()).collect();
        let big: Vec<f64> = (0..20_000).map(|k| k as f64 * 0.25 - 7.0).collect();
        let big_be: Vec<u8> = big.iter().flat_map(|x| x.to_be_bytes()).collect();
        let arrays: Vec<(&str, Vec<u8>)> = vec![
            ("le", raw_npy("<f4", false, "(3, 4)", &le)),
            ("be", raw_npy(">f4", false, "(3, 4)", &be)),
            ("f_le", raw_npy("<f4", true, "(3, 4)", &fortran(&a, f32::to_le_bytes))),
            ("f_be", raw_npy(">f4", true, "(3, 4)", &fortran(&a, f32::to_be_bytes))),
            ("f_be_i8", raw_npy(">i8", true, "(3, 4)", &ints_f)),
            ("f_row", raw_npy("<f4", true, "(1, 12)", &le)),
            ("be_big", raw_npy(">f8", false, "(20000,)", &big_be)),
            // [[T, F, F], [T, T, F]] stored column-major: neither square nor symmetric, so an
            // array read without its transpose differs.
            ("flags", raw_npy("|b1", true, "(2, 3)", &[1, 1, 0, 1, 0, 0])),
        ];
        let mut z = zip::ZipWriter::new(File::create(&path).unwrap());
        for (k, bytes) in &arrays {
            z.start_file(
                format!("{k}.npy"),
                zip::write::FileOptions::default().compression_method(zip::CompressionMethod::Deflated),
            )
            .unwrap();
            z.write_all(bytes).unwrap();
        }
        z.finish().unwrap();
        for key in ["le", "be", "f_le", "f_be", "f_row"] {
            let (got, m) = read_all(&path, key);
            assert_eq!(got, le, "{key}");
            assert_eq!(m.dtype, Dtype::F32, "{key}");
        }
        let (got, m) = read_all(&path, "f_be_i8");
        assert_eq!((m.dtype, m.shape.clone()), (Dtype::I64, vec![3, 4]));
        assert_eq!(got, ints.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>());
        let (got, _) = read_all(&path, "be_big");
        assert_eq!(got, big.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<_>>());
        // Booleans have no byte order; a Fortran-order array is transposed all the same.
        let (flags, m) = read_all(&path, "flags");
        assert_eq!((flags, m.shape), (vec![1, 0, 0, 1, 1, 0], vec![2, 3]));
        assert_eq!(members(&path).unwrap().len(), arrays.len());
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
