//! Writing and reading pgser's Parquet tables: shared writer settings, parallel row-group
//! encoding, and the `pgser` footer.
//!
//! Row groups are encoded in parallel (every column of every row group in a window is its own
//! rayon task) and handed, in order, to one writer thread through a bounded channel. Encoding
//! the next window overlaps writing the last one; the order of appends, and so the bytes of the
//! file, never depend on the thread count; at most two windows are in flight, so memory is
//! bounded by the window size, not the input.

use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{SyncSender, sync_channel};
use std::thread::JoinHandle;

use anyhow::{Context, Result, anyhow, bail};
use arrow_array::RecordBatch;
use arrow_schema::{DataType, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder;
use parquet::arrow::arrow_writer::{ArrowColumnChunk, ArrowRowGroupWriterFactory, compute_leaves};
use parquet::basic::{Compression, Encoding, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::{EnabledStatistics, WriterProperties};
use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::ColumnPath;
use rayon::prelude::*;

use crate::output::AtomicFile;

mod shard;
pub use shard::ShardFile;

/// Footer key-value metadata key holding pgser's JSON description of a table.
pub const FOOTER_KEY: &str = "pgser";
/// Bumped when a table's columns or footer change meaning.
pub const SCHEMA_VERSION: u32 = 1;

/// zstd level 1 (pyarrow's default level for zstd too), no dictionaries (float columns never
/// profit and pay for the attempt), chunk statistics on scalar columns (episode/step ranges let
/// readers skip row groups). Vector leaves get no statistics (min/max of an observation
/// component prunes nothing) and BYTE_STREAM_SPLIT, which groups the bytes of each float by
/// significance: files ~9% smaller for the same time (measured on FetchPush data, BENCHMARKS.md).
fn writer_properties(schema: &Schema) -> WriterProperties {
    let zstd = ZstdLevel::try_new(1).expect("valid level");
    let mut b = WriterProperties::builder()
        .set_compression(Compression::ZSTD(zstd))
        .set_dictionary_enabled(false)
        .set_statistics_enabled(EnabledStatistics::Chunk)
        .set_created_by(format!("pgser {}", env!("CARGO_PKG_VERSION")));
    for f in schema.fields() {
        // An image column's statistics would be two 12 kB values per chunk in the footer, and
        // prune nothing.
        if let DataType::FixedSizeBinary(_) = f.data_type() {
            b = b.set_column_statistics_enabled(ColumnPath::new(vec![f.name().clone()]), EnabledStatistics::None);
        }
        // Float leaves only: a passthrough column may hold lists of bools or integers.
        if let DataType::FixedSizeList(item, _) = f.data_type()
            && matches!(item.data_type(), DataType::Float32 | DataType::Float64)
        {
            let leaf = ColumnPath::new(vec![f.name().clone(), "list".into(), item.name().clone()]);
            b = b
                .set_column_encoding(leaf.clone(), Encoding::BYTE_STREAM_SPLIT)
                .set_column_statistics_enabled(leaf, EnabledStatistics::None);
        }
    }
    b.build()
}

/// A column of `dim`-vectors (Arrow FixedSizeList of non-null float32) over `values`, moved in
/// without a copy: how every pgser writer stores observations, goals and actions.
pub fn f32_vectors(values: Vec<f32>, dim: usize) -> Result<arrow_array::ArrayRef> {
    let item = std::sync::Arc::new(arrow_schema::Field::new("item", DataType::Float32, false));
    let values = std::sync::Arc::new(arrow_array::Float32Array::from(values));
    Ok(std::sync::Arc::new(arrow_array::FixedSizeListArray::try_new(item, dim as i32, values, None)?))
}

type FileWriter = SerializedFileWriter<BufWriter<File>>;

/// The `checksums` key of a `pgser` footer: a CRC-32 of every column chunk's bytes.
///
/// Parquet's own page CRC is optional and arrow-rs 60 does not write it; and float data is stored
/// mostly as raw literals even under zstd, so a flipped bit in a table's pages usually decodes to
/// another valid number, read without complaint. Checksums of each column chunk, kept in the
/// footer's JSON, let every pgser reader check exactly the chunks it reads (a sampler reading
/// four key columns does not pay for the floats), and other readers ignore them safely.
/// Computed by reading each row group back as soon as it is written (from the page cache), so
/// they are of the bytes on disk, not of a buffer that could differ from them.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Checksums {
    /// `"crc32"` (IEEE, as zlib and gzip compute it).
    pub algorithm: String,
    /// `column_chunks[row_group][leaf_column]`: the CRC-32 of that chunk's byte range.
    pub column_chunks: Vec<Vec<u32>>,
    /// The CRC-32 of the rest of the footer: its JSON without this key, keys sorted.
    pub footer: u32,
}

/// The CRC-32 of a footer without its checksums, as [`Checksums::footer`] holds it.
fn footer_crc(footer: &serde_json::Value) -> u32 {
    let mut f = footer.clone();
    f.as_object_mut().map(|m| m.remove(CHECKSUMS_KEY));
    crc32fast::hash(f.to_string().as_bytes())
}

/// The footer's key for [`Checksums`].
pub const CHECKSUMS_KEY: &str = "checksums";

/// CRC-32 of `len` bytes of `file` from `start`, read in blocks with positioned reads (the file's
/// offset is left alone: the writer shares it).
fn crc_range(file: &File, start: u64, len: u64) -> std::io::Result<u32> {
    use std::os::unix::fs::FileExt;
    let mut h = crc32fast::Hasher::new();
    let mut buf = vec![0u8; (len as usize).min(1 << 20)];
    let mut done = 0u64;
    while done < len {
        let n = ((len - done) as usize).min(buf.len());
        file.read_exact_at(&mut buf[..n], start + done)?;
        h.update(&buf[..n]);
        done += n as u64;
    }
    Ok(h.finalize())
}

pub struct TableWriter {
    /// First, so that it is dropped first: the thread is gone before `out` removes the file.
    writer: WriterThread,
    out: AtomicFile,
    factory: ArrowRowGroupWriterFactory,
    schema: SchemaRef,
    row_groups: usize,
}

/// The writer thread and its queue of encoded row groups. A table dropped before `finish` (any
/// error on the way) closes the queue and waits for the thread, so that no thread outlives its
/// table, still holding the file and its writer (found by fuzzing `convert`: LeakSanitizer saw the
/// detached thread's allocations after the call had returned its error).
struct WriterThread {
    tx: Option<SyncSender<Vec<ArrowColumnChunk>>>,
    thread: Option<JoinHandle<Result<Written>>>,
}

impl WriterThread {
    /// Close the queue and wait for the thread: its result, or `None` when already joined.
    fn join(&mut self) -> Option<std::thread::Result<Result<Written>>> {
        self.tx.take();
        self.thread.take().map(JoinHandle::join)
    }
}

impl Drop for WriterThread {
    fn drop(&mut self) {
        let _ = self.join();
    }
}

/// What the writer thread hands back: the file writer and each row group's column-chunk CRCs.
type Written = (FileWriter, Vec<Vec<u32>>);

impl TableWriter {
    pub fn create(dest: &Path, schema: SchemaRef) -> Result<Self> {
        let out = AtomicFile::create(dest)?;
        let buf = BufWriter::with_capacity(8 << 20, out.handle()?);
        let props = writer_properties(&schema);
        // ArrowWriter embeds the Arrow schema (so readers get FixedSizeList back); we then take
        // its lower-level halves to encode columns on our own threads.
        let (writer, factory) = ArrowWriter::try_new(buf, schema.clone(), Some(props))
            .and_then(|w| w.into_serialized_writer())
            .with_context(|| format!("{}: cannot start the Parquet writer", dest.display()))?;
        let (tx, rx) = sync_channel::<Vec<ArrowColumnChunk>>(1);
        let at = dest.to_path_buf();
        let readback = out.handle()?;
        let thread = std::thread::spawn(move || append_all(writer, rx, &at, &readback));
        let writer = WriterThread { tx: Some(tx), thread: Some(thread) };
        Ok(Self { writer, out, factory, schema, row_groups: 0 })
    }

    /// Encode `batches` (one row group each) in parallel and queue them, in order, for writing.
    pub fn write_row_groups(&mut self, batches: &[RecordBatch]) -> Result<()> {
        let first = self.row_groups;
        let encoded: Vec<Vec<ArrowColumnChunk>> =
            batches.par_iter().enumerate().map(|(i, batch)| self.encode(first + i, batch)).collect::<Result<_>>()?;
        for chunks in encoded {
            let tx = self.writer.tx.as_ref().expect("writer open");
            if tx.send(chunks).is_err() {
                // The writer thread stopped early: its error says why.
                return Err(self.join().err().unwrap_or_else(|| anyhow!("writer thread stopped")));
            }
            self.row_groups += 1;
        }
        Ok(())
    }

    fn encode(&self, index: usize, batch: &RecordBatch) -> Result<Vec<ArrowColumnChunk>> {
        let writers = self.factory.create_column_writers(index)?;
        // One task per leaf column; leaves are in schema order, matching `writers`.
        let mut leaves = Vec::with_capacity(writers.len());
        for (field, column) in self.schema.fields().iter().zip(batch.columns()) {
            leaves.extend(compute_leaves(field, column)?);
        }
        writers
            .into_par_iter()
            .zip(leaves.into_par_iter())
            .map(|(mut w, leaf)| {
                w.write(&leaf)?;
                Ok(w.close()?)
            })
            .collect()
    }

    fn join(&mut self) -> Result<Written> {
        let joined = self.writer.join().expect("joined once");
        joined.map_err(|_| anyhow!("{}: writer thread panicked", self.out.dest().display()))?
    }

    /// Write the footer and move the finished file into place. Returns its size in bytes.
    pub fn finish(self, footer: &serde_json::Value) -> Result<u64> {
        let out = self.finish_staged(footer)?;
        let dest: PathBuf = out.dest().to_path_buf();
        out.commit()?;
        Ok(std::fs::metadata(&dest)?.len())
    }

    /// Write the footer but leave the file beside its destination: the caller commits it, so a
    /// table can be put in place together with the files that must agree with it (the online
    /// trainer's replay buffer and its checkpoint).
    pub fn finish_staged(mut self, footer: &serde_json::Value) -> Result<AtomicFile> {
        let dest: PathBuf = self.out.dest().to_path_buf();
        let (mut writer, sums) = self.join()?;
        let mut footer = footer.clone();
        let footer_sum = footer_crc(&footer);
        if let Some(map) = footer.as_object_mut() {
            let sums = Checksums { algorithm: "crc32".into(), column_chunks: sums, footer: footer_sum };
            map.insert(CHECKSUMS_KEY.into(), serde_json::to_value(sums)?);
        }
        writer.append_key_value_metadata(KeyValue::new(FOOTER_KEY.to_string(), footer.to_string()));
        let buf = writer.into_inner().with_context(|| format!("{}: cannot finish the file", dest.display()))?;
        buf.into_inner().map_err(|e| e.into_error()).with_context(|| format!("{}: write failed", dest.display()))?;
        Ok(self.out)
    }
}

/// The writer thread: append row groups in the order they arrive, and checksum each one's
/// column chunks as written (`readback`: a handle on the same file).
fn append_all(
    mut writer: FileWriter,
    rx: std::sync::mpsc::Receiver<Vec<ArrowColumnChunk>>,
    at: &Path,
    readback: &File,
) -> Result<Written> {
    let fail = || format!("{}: write failed", at.display());
    let mut sums = Vec::new();
    for chunks in rx {
        let mut rg = writer.next_row_group().with_context(fail)?;
        for chunk in chunks {
            chunk.append_to_row_group(&mut rg).with_context(fail)?;
        }
        rg.close().with_context(fail)?;
        writer.flush().with_context(fail)?;
        let written = writer.flushed_row_groups().last().expect("a row group was just closed");
        let crcs = written.columns().iter().map(|c| {
            let (start, len) = c.byte_range();
            crc_range(readback, start, len)
        });
        sums.push(
            crcs.collect::<std::io::Result<Vec<u32>>>()
                .with_context(|| format!("{}: cannot read back", at.display()))?,
        );
    }
    Ok((writer, sums))
}

/// Checks a table's column chunks against the checksums in its footer.
pub struct Verifier {
    path: PathBuf,
    /// Byte range of each (row group, leaf column).
    ranges: Vec<Vec<(u64, u64)>>,
    /// Leaf column paths, for messages and [`Verifier::columns_of`].
    leaves: Vec<String>,
    sums: Option<Vec<Vec<u32>>>,
}

impl Verifier {
    /// The checksums of `path` (whose Parquet metadata is `meta`), checked against its layout.
    /// A table without checksums (older pgser, another writer) gets a verifier that checks
    /// nothing ([`Verifier::verifiable`] says so).
    pub fn new(path: &Path, meta: &parquet::file::metadata::ParquetMetaData) -> Result<Verifier> {
        let at = path.display();
        // Not `ColumnChunkMetaData::byte_range`, which panics on the negative offsets a corrupt
        // footer can hold (found by fuzz/fuzz_targets/scored.rs).
        let mut ranges: Vec<Vec<(u64, u64)>> = Vec::new();
        for (g, rg) in meta.row_groups().iter().enumerate() {
            let mut chunks = Vec::new();
            for (c, chunk) in rg.columns().iter().enumerate() {
                let start = chunk.dictionary_page_offset().unwrap_or(chunk.data_page_offset());
                let (Ok(start), Ok(len)) = (u64::try_from(start), u64::try_from(chunk.compressed_size())) else {
                    bail!(
                        "{at}: row group {g}, column {c}: the footer gives a negative offset or length: the file is corrupt"
                    );
                };
                chunks.push((start, len));
            }
            ranges.push(chunks);
        }
        let leaves = meta.file_metadata().schema_descr().columns().iter().map(|c| c.path().string()).collect();
        let footer = footer_text(meta.file_metadata());
        // Checksums describe the file pgser wrote. A file another tool rewrote (pyarrow, polars)
        // can carry the footer over with them, but not the bytes they are of: it is unverifiable,
        // not corrupt.
        let by_pgser = meta.file_metadata().created_by().is_some_and(|c| c.starts_with("pgser "));
        let footer = footer.filter(|_| by_pgser);
        let sums = match footer.map(serde_json::from_str::<serde_json::Value>) {
            Some(Ok(v)) => match v.get(CHECKSUMS_KEY) {
                None => None,
                Some(c) => {
                    let c: Checksums = serde_json::from_value(c.clone()).with_context(|| {
                        format!("{at}: the footer's checksums are not readable: the file is corrupt")
                    })?;
                    if c.algorithm != "crc32" {
                        bail!("{at}: checksums of an unknown algorithm {:?}", c.algorithm);
                    }
                    if footer_crc(&v) != c.footer {
                        bail!("{at}: the `{FOOTER_KEY}` footer does not match its checksum: the file is corrupt");
                    }
                    let shape: Vec<usize> = c.column_chunks.iter().map(Vec::len).collect();
                    if shape != ranges.iter().map(Vec::len).collect::<Vec<_>>() {
                        bail!(
                            "{at}: the footer has checksums for {} row groups but the file has {}: the file is corrupt",
                            shape.len(),
                            ranges.len()
                        );
                    }
                    Some(c.column_chunks)
                }
            },
            Some(Err(_)) => bail!("{at}: the `{FOOTER_KEY}` footer is not valid JSON: the file is corrupt"),
            None => None,
        };
        Ok(Verifier { path: path.to_path_buf(), ranges, leaves, sums })
    }

    /// Whether the file has checksums to check.
    pub fn verifiable(&self) -> bool {
        self.sums.is_some()
    }

    /// The leaf columns under the top-level columns `names` (a vector column has one leaf).
    pub fn columns_of(&self, names: &[&str]) -> Vec<usize> {
        // A column's leaves are `name` or `name.list.item`; a passthrough column's name may hold
        // dots of its own, so the name is matched whole, not cut at the first dot.
        let of = |leaf: &str, name: &str| leaf == name || leaf.strip_prefix(name) == Some(".list.item");
        (0..self.leaves.len()).filter(|&i| names.iter().any(|n| of(&self.leaves[i], n))).collect()
    }

    /// Checks `columns` (leaf indices) of every row group, in parallel on the global rayon pool;
    /// the first mismatch names its row group, column and bytes. A reader of some row groups
    /// reads and checks them through [`ShardFile::read`] instead, on threads of its own.
    pub fn check(&self, columns: &[usize]) -> Result<()> {
        if self.sums.is_none() {
            return Ok(());
        }
        let file = crate::output::open_input(&self.path)?;
        let chunks: Vec<(usize, usize)> =
            (0..self.ranges.len()).flat_map(|rg| columns.iter().map(move |&c| (rg, c))).collect();
        let bad = chunks
            .par_iter()
            .map(|&(rg, c)| -> Result<Option<(usize, usize, u32)>> {
                let (start, len) = self.ranges[rg][c];
                let got = crc_range(&file, start, len).with_context(|| {
                    format!("{}: row group {rg}, column {}: cannot read", self.path.display(), self.leaves[c])
                })?;
                Ok(self.mismatch(rg, c, got))
            })
            .collect::<Result<Vec<_>>>()?;
        match bad.into_iter().flatten().min() {
            Some((rg, c, got)) => Err(self.mismatch_error(rg, c, got)),
            None => Ok(()),
        }
    }

    /// Checks chunk (row group `rg`, leaf `c`) given its bytes, already read (a [`ShardFile`]
    /// read, which decodes these very bytes).
    fn check_bytes(&self, rg: usize, c: usize, bytes: &[u8]) -> Result<()> {
        match self.sums.is_some().then(|| self.mismatch(rg, c, crc32fast::hash(bytes))).flatten() {
            Some((rg, c, got)) => Err(self.mismatch_error(rg, c, got)),
            None => Ok(()),
        }
    }

    /// `Some` when `got` is not the checksum written for chunk (`rg`, `c`).
    fn mismatch(&self, rg: usize, c: usize, got: u32) -> Option<(usize, usize, u32)> {
        let sums = self.sums.as_ref()?;
        (got != sums[rg][c]).then_some((rg, c, got))
    }

    fn mismatch_error(&self, rg: usize, c: usize, got: u32) -> anyhow::Error {
        let (start, len) = self.ranges[rg][c];
        let written = self.sums.as_ref().map_or(0, |s| s[rg][c]);
        anyhow!(
            "{}: row group {rg}, column {}, bytes {start}..{}: checksum mismatch (crc32 {got:08x}, written {written:08x}): the file is corrupt",
            self.path.display(),
            self.leaves[c],
            start + len,
        )
    }

    /// Checks every column chunk.
    pub fn check_all(&self) -> Result<()> {
        self.check(&(0..self.leaves.len()).collect::<Vec<_>>())
    }

    /// Column chunks and bytes that `check_all` covers.
    pub fn extent(&self) -> (usize, u64) {
        let chunks = self.ranges.iter().map(Vec::len).sum();
        (chunks, self.ranges.iter().flatten().map(|r| r.1).sum())
    }
}

/// The raw `pgser` footer (JSON text) in a Parquet file's key-value metadata, if there is one.
pub fn footer_text(meta: &parquet::file::metadata::FileMetaData) -> Option<&str> {
    meta.key_value_metadata()?.iter().find(|e| e.key == FOOTER_KEY)?.value.as_deref()
}

/// Opens a table with its checksums checked first: the column chunks of the top-level
/// `columns` (None: all of them) against the footer's CRC-32s, and the footer against its own.
/// Every door that hands a table's data on without decoding it through pgser (pyarrow through
/// `pgser.read_table`, polars through `pgser-etl query`) comes through here, so a flipped bit
/// gets the one-line error `pgser-etl verify` gives, never other numbers.
pub fn open_checked(
    path: &Path,
    columns: Option<&[&str]>,
) -> Result<(ParquetRecordBatchReaderBuilder<File>, Verifier)> {
    let file = crate::output::open_input(path)?;
    let builder = ParquetRecordBatchReaderBuilder::try_new(file).with_context(|| {
        format!("{}: not a readable Parquet file (its footer is corrupt or it was cut short)", path.display())
    })?;
    let verifier = Verifier::new(path, builder.metadata())?;
    match columns {
        None => verifier.check_all()?,
        Some(names) => verifier.check(&verifier.columns_of(names))?,
    }
    Ok((builder, verifier))
}

/// The `pgser` footer of a Parquet file, parsed, after checking it against its checksum (a
/// table without checksums is taken as it is).
pub fn read_footer(path: &Path) -> Result<serde_json::Value> {
    let file = crate::output::open_input(path)?;
    let reader = SerializedFileReader::new(file).with_context(|| format!("{}: not a Parquet file", path.display()))?;
    Verifier::new(path, reader.metadata())?;
    let text = footer_text(reader.metadata().file_metadata())
        .with_context(|| format!("{}: no `{FOOTER_KEY}` footer: not written by pgser", path.display()))?;
    serde_json::from_str(text)
        .with_context(|| format!("{}: the `{FOOTER_KEY}` footer is not valid JSON", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow_array::{ArrayRef, Float32Array};
    use arrow_schema::Field;
    use std::sync::Arc;

    /// Files open in this process under `dir` (other tests' files live elsewhere).
    fn open_under(dir: &Path) -> usize {
        let fds = std::fs::read_dir("/proc/self/fd").unwrap();
        fds.filter_map(|e| std::fs::read_link(e.ok()?.path()).ok())
            .filter(|p| p.to_string_lossy().starts_with(&*dir.to_string_lossy()))
            .count()
    }

    /// A table dropped before `finish` (an error on the way) has joined its writer thread when the
    /// drop returns: no file of it is still open, and nothing is left in the folder.
    #[test]
    fn a_table_dropped_unfinished_leaves_no_thread_or_file() {
        let dir = tempfile::tempdir().unwrap();
        let schema = Arc::new(Schema::new(vec![Field::new("x", DataType::Float32, false)]));
        let column: ArrayRef = Arc::new(Float32Array::from(vec![1.0f32; 4096]));
        let batch = RecordBatch::try_new(schema.clone(), vec![column]).unwrap();
        for _ in 0..20 {
            let mut w = TableWriter::create(&dir.path().join("t.parquet"), schema.clone()).unwrap();
            w.write_row_groups(&[batch.clone(), batch.clone()]).unwrap();
            assert!(open_under(dir.path()) > 0, "the writer holds its file");
            drop(w);
            assert_eq!(open_under(dir.path()), 0, "a writer thread still holds the file after the drop");
            assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
        }
    }
}
