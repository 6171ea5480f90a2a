//! A pickle reader that executes nothing (and, in [`write`](mod@write), the WGCSL pickle writer).
//!
//! Researchers hand us WGCSL replay buffers as Python pickles. `pickle.load` on such a file runs
//! whatever callables the file names, so a downloaded dataset is a code-execution hazard. This
//! module is a small pickle virtual machine over the opcodes of protocols 0–5 that only *builds
//! values*: dict, list, tuple, set, str, bytes, int, float, bool, None, and numpy arrays. The only
//! globals it resolves are an allow-list (numpy's array/dtype reconstruction, `_codecs.encode`
//! for protocol ≤ 2 bytes, `bytearray`, `set`, `OrderedDict`); every other GLOBAL, STACK_GLOBAL,
//! INST, OBJ, NEWOBJ or persistent id is refused with an error that names it.
//!
//! Memory: the file is memory-mapped and byte strings are *borrowed* from it, so every declared
//! length is checked against the bytes that remain before anything is allocated, and a
//! little-endian C-order array costs no copy at all. Arrays that need byte swapping or a
//! Fortran→C transpose are converted once into an owned buffer.

mod numpy;
mod op;
mod reduce;
pub mod repr;
mod text;
mod vm;
pub mod write;

use std::borrow::Cow;
use std::fmt;
use std::path::Path;

/// numpy's Fortran → C reorder, which the `.npz` reader shares.
pub(crate) use numpy::fortran_to_c;
pub use numpy::{NdArray, PickledDtype, shape_text};

/// Index of an object in a [`Pickle`]'s arena.
pub type Id = usize;

/// A fault in a pickle stream, with the byte offset of the opcode that hit it.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("pickle byte {offset}: {message}")]
pub struct PickleError {
    pub offset: usize,
    pub message: String,
}

/// One value built by the machine. Containers hold ids into the arena, so that a memoized
/// object mutated later (the usual `EMPTY_DICT, MEMOIZE, MARK, …, SETITEMS`) is seen mutated
/// through every reference, exactly as Python would see it.
#[derive(Debug, Clone)]
pub enum Obj<'a> {
    None,
    Bool(bool),
    Int(i64),
    /// An integer that does not fit in i64; kept opaque (little-endian two's complement).
    BigInt(Vec<u8>),
    Float(f64),
    Str(Cow<'a, str>),
    Bytes(Cow<'a, [u8]>),
    List(Vec<Id>),
    Tuple(Vec<Id>),
    Set(Vec<Id>),
    Dict(Vec<(Id, Id)>),
    /// An allow-listed global, only usable as the callable of REDUCE or an argument.
    Global(numpy::Global),
    DType(PickledDtype),
    Array(NdArray<'a>),
    /// `_reconstruct(ndarray, (0,), b'b')` before its BUILD supplies shape, dtype and bytes.
    PendingArray,
    /// A numpy array of a dtype pgser does not read (strings, objects, complex, datetimes),
    /// named by its dtype ("unicode string (<U6)"). Kept in place of the array rather than
    /// refused while parsing, so that a reader can name the key that holds it, and `--drop`
    /// that key: a buffer's metadata often is such an array.
    Unreadable(String),
}

impl Obj<'_> {
    /// Python-ish type name for error messages.
    pub fn type_name(&self) -> &'static str {
        match self {
            Obj::None => "None",
            Obj::Bool(_) => "bool",
            Obj::Int(_) | Obj::BigInt(_) => "int",
            Obj::Float(_) => "float",
            Obj::Str(_) => "str",
            Obj::Bytes(_) => "bytes",
            Obj::List(_) => "list",
            Obj::Tuple(_) => "tuple",
            Obj::Set(_) => "set",
            Obj::Dict(_) => "dict",
            Obj::Global(_) => "global",
            Obj::DType(_) => "numpy dtype",
            Obj::Array(_) | Obj::PendingArray | Obj::Unreadable(_) => "numpy array",
        }
    }
}

/// A parsed pickle: the object arena and the id of the object STOP returned.
#[derive(Debug)]
pub struct Pickle<'a> {
    objs: Vec<Obj<'a>>,
    root: Id,
}

impl<'a> Pickle<'a> {
    /// Run the machine over `data` (a whole pickle stream).
    pub fn parse(data: &'a [u8]) -> Result<Self, PickleError> {
        vm::run(data)
    }

    pub fn root(&self) -> Id {
        self.root
    }

    pub fn get(&self, id: Id) -> &Obj<'a> {
        &self.objs[id]
    }

    /// Move an object out of the arena (leaving None), e.g. to own a large array.
    pub fn take(&mut self, id: Id) -> Obj<'a> {
        std::mem::replace(&mut self.objs[id], Obj::None)
    }

    /// The text of a str, or of bytes that are UTF-8 (Python 2 pickles spell str dict keys as
    /// bytes, and a pickle does not tell the two apart); None for anything else, bytes that are
    /// not UTF-8 included, whose lossy decoding would name a column other than the key.
    pub fn as_text(&self, id: Id) -> Option<Cow<'_, str>> {
        match &self.objs[id] {
            Obj::Str(s) => Some(Cow::Borrowed(s.as_ref())),
            Obj::Bytes(b) => std::str::from_utf8(b).ok().map(Cow::Borrowed),
            _ => None,
        }
    }
}

/// A memory-mapped file, kept alive for as long as parsed values borrow from it.
pub struct MappedFile {
    map: Option<memmap2::Mmap>,
}

impl MappedFile {
    pub fn open(path: &Path) -> std::io::Result<Self> {
        // Not a regular file (a FIFO would block the open forever): refused before opening.
        if !std::fs::metadata(path)?.is_file() {
            return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, "not a regular file; pgser reads files"));
        }
        let file = std::fs::File::open(path)?;
        let len = file.metadata()?.len();
        // mmap of an empty file fails on Linux; an empty slice is the honest answer.
        if len == 0 {
            return Ok(Self { map: None });
        }
        // SAFETY: the map is read-only; a concurrent writer truncating the file could fault,
        // which is the accepted trade-off of every mmap-based reader (ripgrep, polars).
        let map = unsafe { memmap2::Mmap::map(&file)? };
        Ok(Self { map: Some(map) })
    }

    pub fn bytes(&self) -> &[u8] {
        self.map.as_deref().unwrap_or(&[])
    }

    /// Drop the pages under `part` (a slice of this file's bytes) from our resident set once a
    /// job has consumed them, so peak memory follows the work in flight, not the file size.
    /// Reading them again later is still correct: the pages fault back in from the page cache.
    /// Only whole pages inside `part` are released; a slice that is not ours is ignored.
    pub fn release(&self, part: &[u8]) {
        let Some(map) = &self.map else { return };
        let base = map.as_ptr() as usize;
        let start = part.as_ptr() as usize;
        if start < base || start + part.len() > base + map.len() {
            return;
        }
        let page = 4096;
        let from = (start - base).div_ceil(page) * page;
        let to = (start - base + part.len()) / page * page;
        if to > from {
            // SAFETY: a read-only file mapping; DONTNEED only unmaps pages, which are re-read
            // from the file on the next access, so no borrowed slice ever sees other bytes.
            let _ = unsafe { map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, from, to - from) };
        }
    }
}

impl fmt::Debug for MappedFile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "MappedFile({} bytes)", self.bytes().len())
    }
}

#[cfg(test)]
mod tests;
