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

use anyhow::{Context, Result, anyhow};
use arrow_array::RecordBatch;
use arrow_schema::{DataType, Schema, SchemaRef};
use parquet::arrow::ArrowWriter;
use parquet::arrow::arrow_writer::{ArrowColumnChunk, ArrowRowGroupWriterFactory, compute_leaves};
use parquet::basic::{Compression, Encoding, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::{EnabledStatistics, WriterProperties};
use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::file::writer::SerializedFileWriter;
use parquet::schema::types::ColumnPath;
use rayon::prelude::*;

use crate::output::AtomicFile;

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
        if let DataType::FixedSizeList(item, _) = f.data_type() {
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

pub struct TableWriter {
    out: AtomicFile,
    factory: ArrowRowGroupWriterFactory,
    schema: SchemaRef,
    row_groups: usize,
    /// Encoded row groups, in order, to the writer thread.
    tx: Option<SyncSender<Vec<ArrowColumnChunk>>>,
    thread: Option<JoinHandle<Result<FileWriter>>>,
}

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
        let thread = std::thread::spawn(move || append_all(writer, rx, &at));
        Ok(Self { out, factory, schema, row_groups: 0, tx: Some(tx), thread: Some(thread) })
    }

    /// Encode `batches` (one row group each) in parallel and queue them, in order, for writing.
    pub fn write_row_groups(&mut self, batches: &[RecordBatch]) -> Result<()> {
        let first = self.row_groups;
        let encoded: Vec<Vec<ArrowColumnChunk>> =
            batches.par_iter().enumerate().map(|(i, batch)| self.encode(first + i, batch)).collect::<Result<_>>()?;
        for chunks in encoded {
            let tx = self.tx.as_ref().expect("writer open");
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

    fn join(&mut self) -> Result<FileWriter> {
        self.tx.take();
        let thread = self.thread.take().expect("joined once");
        thread.join().map_err(|_| anyhow!("{}: writer thread panicked", self.out.dest().display()))?
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
        let mut writer = self.join()?;
        writer.append_key_value_metadata(KeyValue::new(FOOTER_KEY.to_string(), footer.to_string()));
        let buf = writer.into_inner().with_context(|| format!("{}: cannot finish the file", dest.display()))?;
        buf.into_inner().map_err(|e| e.into_error()).with_context(|| format!("{}: write failed", dest.display()))?;
        Ok(self.out)
    }
}

/// The writer thread: append row groups in the order they arrive.
fn append_all(
    mut writer: FileWriter,
    rx: std::sync::mpsc::Receiver<Vec<ArrowColumnChunk>>,
    at: &Path,
) -> Result<FileWriter> {
    let fail = || format!("{}: write failed", at.display());
    for chunks in rx {
        let mut rg = writer.next_row_group().with_context(fail)?;
        for chunk in chunks {
            chunk.append_to_row_group(&mut rg).with_context(fail)?;
        }
        rg.close().with_context(fail)?;
    }
    Ok(writer)
}

/// The `pgser` footer of a Parquet file, parsed.
pub fn read_footer(path: &Path) -> Result<serde_json::Value> {
    let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let reader = SerializedFileReader::new(file).with_context(|| format!("{}: not a Parquet file", path.display()))?;
    let kv = reader.metadata().file_metadata().key_value_metadata();
    let text = kv
        .and_then(|kv| kv.iter().find(|e| e.key == FOOTER_KEY))
        .and_then(|e| e.value.clone())
        .with_context(|| format!("{}: no `{FOOTER_KEY}` footer: not written by pgser", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: the `{FOOTER_KEY}` footer is not valid JSON", path.display()))
}
