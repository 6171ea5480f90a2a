//! What a table keeps of its sources' other arrays, and what an export writes of its passthrough
//! columns: the same arrays in every source, and nothing a format cannot hold left out unasked.
//! Each refusal names the array and gives the `--drop` that leaves it out.

use anyhow::{Result, bail};

use super::Passthrough;
use crate::trajectory::Footer;

/// The passthrough arrays of several sources made into one list: the same keys, with the same
/// layout, dtype and shape, in every source (or the first difference, named, with `--drop`).
/// `files` of each record lists every source that had it.
pub fn merge(per_source: &[(String, Vec<Passthrough>)]) -> Result<Vec<Passthrough>> {
    let Some((first_at, first)) = per_source.first() else { return Ok(Vec::new()) };
    let mut merged = first.clone();
    for (at, specs) in &per_source[1..] {
        for p in specs {
            match merged.iter_mut().find(|m| m.column == p.column) {
                Some(m) if (m.per, &m.dtype, &m.shape) == (p.per, &p.dtype, &p.shape) => m.files.push(at.clone()),
                Some(m) => bail!(
                    "{at}: key '{}' is {} of shape {:?} per {:?} where {first_at} has {} of shape {:?} per {:?}; pass --drop {} \
                     to convert without it",
                    p.column,
                    p.dtype,
                    p.shape,
                    p.per,
                    m.dtype,
                    m.shape,
                    m.per,
                    p.column
                ),
                None => bail!(
                    "{at}: key '{}' is not in {first_at}: a table's episodes all have the same columns; pass --drop {} to \
                     convert without it",
                    p.column,
                    p.column
                ),
            }
        }
        if let Some(m) = merged.iter().find(|m| !specs.iter().any(|p| p.column == m.column)) {
            bail!(
                "{at}: has no key '{}', which {first_at} has: a table's episodes all have the same columns; pass --drop {} \
                 to convert without it",
                m.column,
                m.column
            );
        }
    }
    Ok(merged)
}

/// What `--drop` calls each episode's last action (OGBench's files have one on their last row;
/// the table keeps it on step T − 1).
pub const LAST_ACTION: &str = "last_action";

/// What a table holds beyond pgser's four arrays, less what `drop` leaves out, with what the
/// format cannot hold refused by name (`holds`: whether the format can hold a passthrough
/// column; `last_action`: whether it can hold the last actions). Checked before any output
/// exists. Returns the passthrough columns to write, and whether to write the last actions.
pub fn kept_for(
    footer: &Footer,
    table: &std::path::Path,
    format: &str,
    drop: &[String],
    holds: impl Fn(&Passthrough) -> bool,
    last_action: bool,
) -> Result<(Vec<Passthrough>, bool)> {
    let at = table.display();
    for d in drop {
        if d != LAST_ACTION && !footer.passthrough.iter().any(|p| p.column == *d) {
            let have: Vec<&str> = footer.passthrough.iter().map(|p| p.column.as_str()).collect();
            bail!(
                "--drop {d}: {at} has no passthrough column {d:?} (it has: {})",
                if have.is_empty() { "none".into() } else { have.join(", ") }
            );
        }
    }
    let mut kept = Vec::new();
    for p in footer.passthrough.iter().filter(|p| !drop.contains(&p.column)) {
        if !holds(p) {
            bail!(
                "{at}: a {format} file cannot hold the passthrough column {} ({} of shape {:?}, one per {:?}); pass --drop {} \
                 to export without it",
                p.column,
                p.dtype,
                p.shape,
                p.per,
                p.column
            );
        }
        kept.push(p.clone());
    }
    let keep_last = footer.last_action && !drop.iter().any(|d| d == LAST_ACTION);
    if keep_last && !last_action {
        bail!(
            "{at}: a {format} file cannot hold each episode's last action (the table keeps the one its source had on \
             step T − 1); pass --drop {LAST_ACTION} to export without them"
        );
    }
    Ok((kept, keep_last))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::trajectory::Per;

    #[test]
    fn sources_must_agree_on_their_passthrough_arrays() {
        let p = |at: &str, key: &str, d: &str| {
            Passthrough::new(at, key, crate::dtype::Dtype::parse(d).unwrap(), Per::Transition, vec![1]).unwrap()
        };
        let m = merge(&[("a".into(), vec![p("a", "s", "<f8")]), ("b".into(), vec![p("b", "s", "<f8")])]).unwrap();
        assert_eq!(m[0].files, ["a", "b"]);
        let e = merge(&[("a".into(), vec![p("a", "s", "<f8")]), ("b".into(), vec![p("b", "s", "<f4")])]).unwrap_err();
        assert!(e.to_string().contains("b: key 's' is <f4") && e.to_string().contains("--drop s"), "{e}");
        let e = merge(&[("a".into(), vec![p("a", "s", "<f8")]), ("b".into(), vec![])]).unwrap_err();
        assert!(e.to_string().contains("b: has no key 's'"), "{e}");
        let e = merge(&[("a".into(), vec![]), ("b".into(), vec![p("b", "s", "<f8")])]).unwrap_err();
        assert!(e.to_string().contains("b: key 's' is not in a"), "{e}");
    }
}
