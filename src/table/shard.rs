//! One shard of a table (a Parquet file pgser wrote), opened for reading row groups: its Parquet
//! metadata parsed and its checksums read once, at open, and each read of `(groups, columns)`
//! served from the very bytes its checksums were checked on.
//!
//! Why the bytes are held: checking a column chunk's CRC-32 and then letting the Parquet decoder
//! read the file again leaves a window in which the file can change between the two reads (a
//! shard rewritten while a pool trains on it), and it reads every chunk twice. Here a read
//! fetches each chunk once (`pread`, on up to four threads of its own, never the global rayon
//! pool: the out-of-core pool's loader calls this and must not wait on that pool), checks it, and
//! hands the decoder a [`ChunkReader`] over those buffers alone. A page the decoder asks for
//! outside them is an error, not a read of the file.
//!
//! The memory of a read is the compressed size of the chunks it decodes, held until the returned
//! reader is dropped: for the pool, a block's columns (the plan's blocks in flight count a block
//! at its decoded size, which is never smaller).

use std::fs::File;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, anyhow, bail};
use bytes::{Buf, Bytes};
use parquet::arrow::ProjectionMask;
use parquet::arrow::arrow_reader::{
    ArrowReaderMetadata, ArrowReaderOptions, ParquetRecordBatchReader, ParquetRecordBatchReaderBuilder, RowSelection,
};
use parquet::file::metadata::ParquetMetaData;
use parquet::file::reader::{ChunkReader, Length};

use super::{Verifier, footer_text};

/// A shard's file, opened: what every later read of it is checked against.
pub struct ShardFile {
    path: PathBuf,
    meta: ArrowReaderMetadata,
    verifier: Verifier,
    identity: Identity,
}

/// What tells one file from another at the same path: device, inode, size, modification time.
/// A read from a file whose identity changed since open is refused as changed, not decoded
/// against metadata that is no longer its own.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Identity {
    dev: u64,
    ino: u64,
    len: u64,
    modified: Option<std::time::SystemTime>,
}

impl Identity {
    fn of(file: &File, path: &Path) -> Result<Identity> {
        let m = file.metadata().with_context(|| format!("{}: cannot stat", path.display()))?;
        #[cfg(unix)]
        let (dev, ino) = {
            use std::os::unix::fs::MetadataExt;
            (m.dev(), m.ino())
        };
        #[cfg(not(unix))]
        let (dev, ino) = (0, 0);
        Ok(Identity { dev, ino, len: m.len(), modified: m.modified().ok() })
    }
}

impl ShardFile {
    /// Opens `path`: its Parquet metadata parsed, its `pgser` footer checked against its checksum
    /// and its checksums against its layout ([`Verifier::new`]). Nothing else is read.
    pub fn open(path: &Path) -> Result<ShardFile> {
        let file = crate::output::open_input(path)?;
        let identity = Identity::of(&file, path)?;
        let meta = ArrowReaderMetadata::load(&file, ArrowReaderOptions::new()).with_context(|| {
            format!("{}: not a readable Parquet file (its footer is corrupt or it was cut short)", path.display())
        })?;
        let verifier = Verifier::new(path, meta.metadata())?;
        Ok(ShardFile { path: path.to_path_buf(), meta, verifier, identity })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn metadata(&self) -> &ParquetMetaData {
        self.meta.metadata()
    }

    /// The raw `pgser` footer (JSON text), if the file has one.
    pub fn footer_text(&self) -> Option<&str> {
        footer_text(self.meta.metadata().file_metadata())
    }

    /// The `pgser` footer, parsed (its checksum was checked at open), with [`read_footer`]'s
    /// messages.
    ///
    /// [`read_footer`]: super::read_footer
    pub fn footer_json(&self) -> Result<serde_json::Value> {
        let at = self.path.display();
        let text = self
            .footer_text()
            .with_context(|| format!("{at}: no `{}` footer: not written by pgser", super::FOOTER_KEY))?;
        serde_json::from_str(text)
            .with_context(|| format!("{at}: the `{}` footer is not valid JSON", super::FOOTER_KEY))
    }

    /// Each row group's row count; a negative one (a corrupt footer) is refused by row group.
    pub fn group_rows(&self) -> Result<Vec<usize>> {
        let groups = self.meta.metadata().row_groups().iter().enumerate();
        groups
            .map(|(g, rg)| {
                usize::try_from(rg.num_rows()).map_err(|_| {
                    anyhow!("{}: row group {g} has a negative row count: the file is corrupt", self.path.display())
                })
            })
            .collect()
    }

    /// Checks the chunks of the top-level `columns` in every row group against their checksums, in
    /// parallel on the global rayon pool: what a reader that holds the whole table calls first.
    pub fn check(&self, columns: &[&str]) -> Result<()> {
        self.verifier.check(&self.verifier.columns_of(columns))
    }

    /// A reader of the top-level `columns` of row groups `groups` (in order), optionally only the
    /// rows `rows` selects within them, `batch_rows` rows a record batch. Every chunk it decodes
    /// has been read once and checked against the footer's checksum before this returns; the
    /// file must be the one opened.
    pub fn read(
        &self,
        groups: &[usize],
        columns: &[&str],
        rows: Option<RowSelection>,
        batch_rows: usize,
    ) -> Result<ParquetRecordBatchReader> {
        let at = self.path.display();
        let schema = self.meta.schema();
        let roots = columns
            .iter()
            .map(|n| schema.index_of(n).map_err(|_| anyhow!("{at}: no `{n}` column")))
            .collect::<Result<Vec<_>>>()?;
        let file = crate::output::open_input(&self.path)?;
        if Identity::of(&file, &self.path)? != self.identity {
            bail!(
                "{at}: the file changed since it was opened (replaced or rewritten while it was read); start again \
                 on data that stays as it is"
            );
        }
        let leaves = self.verifier.columns_of(columns);
        let chunks = self.verifier.read_checked(&file, groups, &leaves)?;
        let source = Chunks { len: self.identity.len, chunks };
        let builder = ParquetRecordBatchReaderBuilder::new_with_metadata(source, self.meta.clone());
        let mask = ProjectionMask::roots(builder.parquet_schema(), roots);
        let mut builder =
            builder.with_projection(mask).with_row_groups(groups.to_vec()).with_batch_size(batch_rows.max(1));
        if let Some(rows) = rows {
            builder = builder.with_row_selection(rows);
        }
        builder.build().with_context(|| format!("{at}: cannot read"))
    }
}

/// The column chunks a read fetched, by file offset: the only bytes its decoder may see.
struct Chunks {
    /// The file's length (what [`Length`] reports; the metadata is never read through here).
    len: u64,
    /// (offset in the file, bytes), sorted by offset, not overlapping.
    chunks: Vec<(u64, Bytes)>,
}

impl Chunks {
    /// The bytes from file offset `start` to the end of the chunk that holds it.
    fn from(&self, start: u64) -> parquet::errors::Result<Bytes> {
        let i = self.chunks.partition_point(|(o, _)| *o <= start);
        let found = i.checked_sub(1).map(|i| &self.chunks[i]).filter(|(o, b)| start < o + b.len() as u64);
        match found {
            Some((o, b)) => Ok(b.slice((start - o) as usize..)),
            None => Err(parquet::errors::ParquetError::General(format!(
                "byte {start} lies outside the column chunks read (the file's metadata points elsewhere: it is corrupt)"
            ))),
        }
    }
}

impl Length for Chunks {
    fn len(&self) -> u64 {
        self.len
    }
}

impl ChunkReader for Chunks {
    type T = bytes::buf::Reader<Bytes>;

    fn get_read(&self, start: u64) -> parquet::errors::Result<Self::T> {
        Ok(self.from(start)?.reader())
    }

    fn get_bytes(&self, start: u64, length: usize) -> parquet::errors::Result<Bytes> {
        let b = self.from(start)?;
        if b.len() < length {
            return Err(parquet::errors::ParquetError::General(format!(
                "bytes {start}..{} run past the column chunk that holds byte {start} (the file is corrupt)",
                start + length as u64
            )));
        }
        Ok(b.slice(..length))
    }
}

impl Verifier {
    /// The chunks `columns` (leaf indices) of row groups `groups`, each read once from `file` and
    /// checked against its checksum (when the file has checksums), sorted by offset. Up to four
    /// threads of its own read them; the first mismatch in (row group, column) order is reported.
    fn read_checked(&self, file: &File, groups: &[usize], columns: &[usize]) -> Result<Vec<(u64, Bytes)>> {
        use std::os::unix::fs::FileExt;
        let wanted: Vec<(usize, usize)> = groups.iter().flat_map(|&rg| columns.iter().map(move |&c| (rg, c))).collect();
        let one = |&(rg, c): &(usize, usize)| -> Result<(u64, Bytes)> {
            let (start, len) = self.ranges[rg][c];
            let len = usize::try_from(len).map_err(|_| anyhow!("{}: a chunk too large", self.path.display()))?;
            // Zeroed by calloc: a large one is a fresh mapping, zero already.
            let mut buf = vec![0u8; len];
            file.read_exact_at(&mut buf, start).with_context(|| {
                format!("{}: row group {rg}, column {}: cannot read", self.path.display(), self.leaves[c])
            })?;
            self.check_bytes(rg, c, &buf)?;
            Ok((start, Bytes::from(buf)))
        };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get()).clamp(1, 4).min(wanted.len()).max(1);
        // Thread i reads chunks i, i + threads, …: chunks of one column are alike in size.
        let part = |i: usize| -> Vec<(usize, Result<(u64, Bytes)>)> {
            (i..wanted.len()).step_by(threads).map(|k| (k, one(&wanted[k]))).collect()
        };
        let mut all: Vec<(usize, Result<(u64, Bytes)>)> = std::thread::scope(|scope| {
            let others: Vec<_> = (1..threads).map(|i| scope.spawn(move || part(i))).collect();
            let mut all = part(0);
            for h in others {
                all.extend(h.join().expect("a chunk reader does not panic"));
            }
            all
        });
        all.sort_by_key(|(k, _)| *k);
        let mut chunks = all.into_iter().map(|(_, r)| r).collect::<Result<Vec<_>>>()?;
        chunks.sort_by_key(|(o, _)| *o);
        if let Some(w) = chunks.windows(2).find(|w| w[0].0 + w[0].1.len() as u64 > w[1].0) {
            bail!(
                "{}: column chunks at bytes {} and {} overlap: the file is corrupt",
                self.path.display(),
                w[0].0,
                w[1].0
            );
        }
        Ok(chunks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow_array::cast::AsArray;
    use arrow_array::types::Float32Type;
    use arrow_array::{ArrayRef, Float32Array, RecordBatch};
    use arrow_schema::{DataType, Field, Schema};
    use std::sync::Arc;

    /// A pgser table of one float column `x`, two row groups of 1000 rows: x = row number.
    fn table(path: &Path) {
        let schema = Arc::new(Schema::new(vec![Field::new("x", DataType::Float32, false)]));
        let group = |g: usize| {
            let x: ArrayRef = Arc::new(Float32Array::from_iter_values((0..1000).map(|i| (g * 1000 + i) as f32)));
            RecordBatch::try_new(schema.clone(), vec![x]).unwrap()
        };
        let mut w = super::super::TableWriter::create(path, schema.clone()).unwrap();
        w.write_row_groups(&[group(0), group(1)]).unwrap();
        w.finish(&serde_json::json!({"kind": "test"})).unwrap();
    }

    fn values(reader: ParquetRecordBatchReader) -> Result<Vec<f32>> {
        let mut out = Vec::new();
        for b in reader {
            out.extend(b?.column(0).as_primitive::<Float32Type>().values().iter());
        }
        Ok(out)
    }

    /// Flips one byte of row group `g`'s chunk of `x` in place: same file, same size, its
    /// modification time put back, so nothing but the bytes tells it changed.
    fn flip_in_place(path: &Path, file: &ShardFile, g: usize) {
        use std::os::unix::fs::FileExt;
        let (start, len) = file.verifier.ranges[g][0];
        let f = std::fs::OpenOptions::new().write(true).read(true).open(path).unwrap();
        let modified = f.metadata().unwrap().modified().unwrap();
        let at = start + len / 2;
        let mut b = [0u8];
        f.read_exact_at(&mut b, at).unwrap();
        f.write_all_at(&[b[0] ^ 0x10], at).unwrap();
        f.set_modified(modified).unwrap();
    }

    /// A read decodes the bytes it checked: a chunk changed on disk after the read began (the
    /// window between a check and a decode that reads the file again) changes nothing it yields,
    /// and the next read of it is refused as corrupt, naming the row group and column.
    #[test]
    fn a_read_decodes_the_bytes_it_checked_and_a_later_read_sees_the_change() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        table(&path);
        let file = ShardFile::open(&path).unwrap();
        assert_eq!(file.group_rows().unwrap(), [1000, 1000]);
        let reader = file.read(&[0, 1], &["x"], None, 256).unwrap();
        flip_in_place(&path, &file, 1);
        let got = values(reader).unwrap();
        assert_eq!(got, (0..2000).map(|i| i as f32).collect::<Vec<_>>());
        let only_first = values(file.read(&[0], &["x"], None, 256).unwrap()).unwrap();
        assert_eq!(only_first.len(), 1000);
        let e = format!("{:#}", file.read(&[1], &["x"], None, 256).err().expect("the changed chunk is refused"));
        assert!(
            e.contains("t.parquet") && e.contains("row group 1, column x") && e.contains("checksum mismatch"),
            "{e}"
        );
        let e = format!("{:#}", file.read(&[0], &["y"], None, 256).err().expect("no such column"));
        assert!(e.contains("no `y` column"), "{e}");
    }

    /// A file put in place of the one opened (renamed over it) is refused as changed.
    #[test]
    fn a_file_replaced_after_open_is_refused_as_changed() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.parquet");
        table(&path);
        let file = ShardFile::open(&path).unwrap();
        table(&dir.path().join("u.parquet"));
        std::fs::rename(dir.path().join("u.parquet"), &path).unwrap();
        let e = format!("{:#}", file.read(&[0], &["x"], None, 256).err().expect("refused"));
        assert!(e.contains("changed since it was opened"), "{e}");
    }

    fn chunks() -> Chunks {
        Chunks { len: 100, chunks: vec![(10, Bytes::from_static(b"abcdef")), (40, Bytes::from_static(b"0123456789"))] }
    }

    /// Reads inside a fetched chunk give its bytes; a read that starts outside every chunk, or
    /// runs past the end of the one it starts in, is an error and never a read of other bytes.
    #[test]
    fn a_decoder_sees_only_the_chunks_read() {
        let c = chunks();
        assert_eq!(&c.get_bytes(10, 6).unwrap()[..], b"abcdef");
        assert_eq!(&c.get_bytes(12, 2).unwrap()[..], b"cd");
        assert_eq!(&c.get_bytes(45, 5).unwrap()[..], b"56789");
        let mut r = c.get_read(43).unwrap();
        let mut s = String::new();
        std::io::Read::read_to_string(&mut r, &mut s).unwrap();
        assert_eq!(s, "3456789");
        for (start, len) in [(0, 1), (9, 2), (16, 1), (30, 1), (50, 1), (99, 1)] {
            assert!(c.get_bytes(start, len).is_err(), "bytes {start}..+{len} are outside the chunks");
        }
        assert!(c.get_bytes(14, 3).unwrap_err().to_string().contains("run past"));
        assert!(c.get_read(16).is_err());
    }
}
