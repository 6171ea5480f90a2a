//! Writing and reading pgser's Parquet tables: shared writer settings, parallel row-group
//! encoding, and the `pgser` footer.
//!
//! Row groups are encoded in parallel (every column of every row group in a window is its own
//! rayon task) and appended strictly in order, so the bytes of a file never depend on the
//! thread count.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use anyhow::{Context, Result};
use arrow_array::RecordBatch;
use arrow_schema::SchemaRef;
use parquet::arrow::ArrowWriter;
use parquet::arrow::arrow_writer::{ArrowColumnChunk, ArrowRowGroupWriterFactory, compute_leaves};
use parquet::basic::{Compression, ZstdLevel};
use parquet::file::metadata::KeyValue;
use parquet::file::properties::{EnabledStatistics, WriterProperties};
use parquet::file::reader::{FileReader, SerializedFileReader};
use parquet::file::writer::SerializedFileWriter;
use rayon::prelude::*;

use crate::output::AtomicFile;

/// Footer key-value metadata key holding pgser's JSON description of a table.
pub const FOOTER_KEY: &str = "pgser";
/// Bumped when a table's columns or footer change meaning.
pub const SCHEMA_VERSION: u32 = 1;

/// zstd level 1 (fast, and what pyarrow uses by default for zstd), no dictionaries (float
/// columns never profit and pay for the attempt), chunk-level statistics only.
fn writer_properties() -> WriterProperties {
    WriterProperties::builder()
        .set_compression(Compression::ZSTD(
            ZstdLevel::try_new(1).expect("valid level"),
        ))
        .set_dictionary_enabled(false)
        .set_statistics_enabled(EnabledStatistics::Chunk)
        .set_created_by(format!("pgser {}", env!("CARGO_PKG_VERSION")))
        .build()
}

pub struct TableWriter {
    out: AtomicFile,
    writer: SerializedFileWriter<BufWriter<File>>,
    factory: ArrowRowGroupWriterFactory,
    schema: SchemaRef,
    row_groups: usize,
}

impl TableWriter {
    pub fn create(dest: &Path, schema: SchemaRef) -> Result<Self> {
        let out = AtomicFile::create(dest)?;
        let buf = BufWriter::with_capacity(8 << 20, out.handle()?);
        // ArrowWriter embeds the Arrow schema (so readers get FixedSizeList back); we then take
        // its lower-level halves to encode columns on our own threads.
        let (writer, factory) =
            ArrowWriter::try_new(buf, schema.clone(), Some(writer_properties()))
                .and_then(|w| w.into_serialized_writer())
                .with_context(|| format!("{}: cannot start the Parquet writer", dest.display()))?;
        Ok(Self {
            out,
            writer,
            factory,
            schema,
            row_groups: 0,
        })
    }

    /// Encode `batches` (one row group each) in parallel and append them in order.
    pub fn write_row_groups(&mut self, batches: &[RecordBatch]) -> Result<()> {
        let first = self.row_groups;
        let encoded: Vec<Vec<ArrowColumnChunk>> = batches
            .par_iter()
            .enumerate()
            .map(|(i, batch)| self.encode(first + i, batch))
            .collect::<Result<_>>()?;
        let dest = self.out.dest().display().to_string();
        for chunks in encoded {
            let mut rg = self
                .writer
                .next_row_group()
                .with_context(|| format!("{dest}: write failed"))?;
            for chunk in chunks {
                chunk
                    .append_to_row_group(&mut rg)
                    .with_context(|| format!("{dest}: write failed"))?;
            }
            rg.close()
                .with_context(|| format!("{dest}: write failed"))?;
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

    /// Write the footer and move the finished file into place. Returns its size in bytes.
    pub fn finish(mut self, footer: &serde_json::Value) -> Result<u64> {
        let dest = self.out.dest().to_path_buf();
        self.writer
            .append_key_value_metadata(KeyValue::new(FOOTER_KEY.to_string(), footer.to_string()));
        let buf = self
            .writer
            .into_inner()
            .with_context(|| format!("{}: cannot finish the file", dest.display()))?;
        buf.into_inner()
            .map_err(|e| e.into_error())
            .with_context(|| format!("{}: write failed", dest.display()))?;
        self.out.commit()?;
        Ok(std::fs::metadata(&dest)?.len())
    }
}

/// The `pgser` footer of a Parquet file, parsed.
pub fn read_footer(path: &Path) -> Result<serde_json::Value> {
    let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
    let reader = SerializedFileReader::new(file)
        .with_context(|| format!("{}: not a Parquet file", path.display()))?;
    let kv = reader.metadata().file_metadata().key_value_metadata();
    let text = kv
        .and_then(|kv| kv.iter().find(|e| e.key == FOOTER_KEY))
        .and_then(|e| e.value.clone())
        .with_context(|| {
            format!(
                "{}: no `{FOOTER_KEY}` footer: not written by pgser",
                path.display()
            )
        })?;
    serde_json::from_str(&text).with_context(|| {
        format!(
            "{}: the `{FOOTER_KEY}` footer is not valid JSON",
            path.display()
        )
    })
}
