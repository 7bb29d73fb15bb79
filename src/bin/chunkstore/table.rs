//! Record batches as a text table a person reads on a terminal: cells cut to a width,
//! rows cut to a count, the rest counted. `sql` prints results this way on a terminal, and
//! `dataframe` does where it would otherwise write binary Arrow IPC to one. A pipe or a
//! file gets everything (`sql`: the whole table; `dataframe`: the IPC stream).
//!
//! A cell of an image holds thousands of numbers: printing whole cells made a 1.5 MB
//! table take seconds to lay out and scroll, and the first rows are what a person looks
//! at before asking for the rest with `--json` or `--out`.

use std::io::Write;

use arrow_array::RecordBatch;
use arrow_cast::display::{ArrayFormatter, FormatOptions};
use arrow_schema::{ArrowError, Schema};

/// How much of a table a terminal shows.
#[derive(Debug, Clone, Copy)]
pub struct Limits {
    /// Rows shown; the others are counted.
    pub rows: usize,
    /// Characters of a cell shown; a longer one ends in `…`.
    pub cell_chars: usize,
}

impl Limits {
    /// What fits a terminal screen or two.
    pub const TERMINAL: Self = Self {
        rows: 40,
        cell_chars: 40,
    };
}

/// `text` cut to `limit` characters, the last one `…` if anything was cut, on one line.
fn cut(text: &str, limit: usize) -> String {
    let one_line = text.replace(['\n', '\r'], " ");
    if one_line.chars().count() <= limit {
        return one_line;
    }
    let mut out: String = one_line.chars().take(limit.saturating_sub(1)).collect();
    out.push('…');
    out
}

/// Writes the table (header, rule, rows) within `limits`; returns the rows left out.
///
/// # Errors
/// Arrow's, if a column cannot be formatted, and the writer's.
pub fn write(
    out: &mut impl Write,
    schema: &Schema,
    batches: &[RecordBatch],
    limits: Limits,
) -> Result<usize, ArrowError> {
    let options = FormatOptions::default().with_null("null");
    let mut rows: Vec<Vec<String>> = Vec::new();
    let total: usize = batches.iter().map(RecordBatch::num_rows).sum();
    'batches: for batch in batches {
        let formatters = batch
            .columns()
            .iter()
            .map(|column| ArrayFormatter::try_new(column.as_ref(), &options))
            .collect::<Result<Vec<_>, _>>()?;
        for row in 0..batch.num_rows() {
            if rows.len() == limits.rows {
                break 'batches;
            }
            rows.push(
                formatters
                    .iter()
                    .map(|f| cut(&f.value(row).to_string(), limits.cell_chars))
                    .collect(),
            );
        }
    }
    let header: Vec<String> = schema
        .fields()
        .iter()
        .map(|f| cut(f.name(), limits.cell_chars))
        .collect();
    let widths: Vec<usize> = (0..header.len())
        .map(|c| {
            rows.iter()
                .map(|r| r[c].chars().count())
                .chain([header[c].chars().count()])
                .max()
                .unwrap_or(0)
        })
        .collect();
    let line = |cells: &[String]| -> String {
        cells
            .iter()
            .zip(&widths)
            .map(|(cell, &width)| format!("{cell:<width$}"))
            .collect::<Vec<_>>()
            .join(" | ")
            .trim_end()
            .to_owned()
    };
    let io = |e: std::io::Error| ArrowError::IoError(e.to_string(), e);
    writeln!(out, "{}", line(&header)).map_err(io)?;
    let rule: Vec<String> = widths.iter().map(|&w| "-".repeat(w)).collect();
    writeln!(out, "{}", rule.join("-+-")).map_err(io)?;
    for row in &rows {
        writeln!(out, "{}", line(row)).map_err(io)?;
    }
    Ok(total - rows.len())
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{ArrayRef, Int64Array, StringArray};

    use super::*;

    #[test]
    fn long_cells_and_many_rows_are_cut_and_counted() {
        let long = "x".repeat(100);
        let batch = RecordBatch::try_from_iter([
            (
                "n",
                Arc::new(Int64Array::from((0..10).collect::<Vec<i64>>())) as ArrayRef,
            ),
            (
                "text",
                Arc::new(StringArray::from(
                    (0..10)
                        .map(|i| (i != 3).then_some(long.as_str()))
                        .collect::<Vec<_>>(),
                )) as ArrayRef,
            ),
        ])
        .unwrap();
        let mut out = Vec::new();
        let limits = Limits {
            rows: 4,
            cell_chars: 8,
        };
        let omitted = write(&mut out, &batch.schema(), &[batch.clone(), batch], limits).unwrap();
        assert_eq!(omitted, 16);
        let text = String::from_utf8(out).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(
            lines,
            [
                "n | text",
                "--+---------",
                "0 | xxxxxxx…",
                "1 | xxxxxxx…",
                "2 | xxxxxxx…",
                "3 | null",
            ]
        );
    }
}
