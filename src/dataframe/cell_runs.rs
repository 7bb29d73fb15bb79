//! [`ColumnCells`]: one column's cells of a batch of the `chunks` table, recorded as runs
//! while the table fills many columns a row at a time, and replayed into a
//! [`ListColumnBuilder`] when the batch ends.

use arrow_schema::ArrowError;

use super::cells::{Cell, ListColumnBuilder, Sources};

/// One batch's cells of one column, as runs. A column the merge does not touch at a row
/// is not visited: it is padded (with nulls, its static cell or its fill value) when it
/// is next touched or the batch ends, so a sparse row costs only the columns it has.
#[derive(Debug, Default)]
pub(crate) struct ColumnCells {
    /// The run cells are being added to, kept beside the column's other fields rather
    /// than at the end of `runs`: the merge touches every column of a row, and reading a
    /// run through its vector would be one more cache miss per cell.
    last: Option<CellRun>,
    /// The finished runs before it.
    runs: Vec<CellRun>,
    len: usize,
}

#[derive(Clone, Copy, Debug)]
enum CellRun {
    Nulls(u32),
    Empties(u32),
    /// `nulls_before` null cells, then rows `start..start + len` of `source`. A sparse
    /// column alternates nulls and rows; folding each gap into the run after it makes
    /// that one run per cell, not two.
    Rows {
        nulls_before: u32,
        source: u32,
        start: u32,
        len: u32,
    },
    /// One row, repeated.
    Repeat {
        source: u32,
        row: u32,
        times: u32,
    },
}

impl ColumnCells {
    /// Appends copies of `cell` until the column holds `len` cells.
    #[expect(clippy::cast_possible_truncation, reason = "a batch holds < 2^32 rows")]
    pub fn pad(&mut self, cell: Option<Cell>, len: usize) {
        let Some(missing) = len.checked_sub(self.len).filter(|&n| n > 0) else {
            return;
        };
        match cell {
            Some(Cell::Row { source, row }) => {
                self.push(cell);
                let extra = (missing - 1) as u32;
                if extra > 0 {
                    self.open(CellRun::Repeat {
                        source,
                        row,
                        times: extra,
                    });
                    self.len += extra as usize;
                }
            }
            None => {
                match &mut self.last {
                    Some(CellRun::Nulls(n)) => *n += missing as u32,
                    _ => self.open(CellRun::Nulls(missing as u32)),
                }
                self.len = len;
            }
            Some(Cell::Empty) => {
                match &mut self.last {
                    Some(CellRun::Empties(n)) => *n += missing as u32,
                    _ => self.open(CellRun::Empties(missing as u32)),
                }
                self.len = len;
            }
        }
    }

    pub fn push(&mut self, cell: Option<Cell>) {
        self.len += 1;
        match (&mut self.last, cell) {
            (Some(CellRun::Nulls(n)), None) | (Some(CellRun::Empties(n)), Some(Cell::Empty)) => {
                *n += 1;
            }
            (
                Some(CellRun::Rows {
                    source, start, len, ..
                }),
                Some(Cell::Row { source: s, row }),
            ) if *source == s && *start + *len == row => {
                *len += 1;
            }
            (Some(CellRun::Nulls(n)), Some(Cell::Row { source, row })) => {
                let nulls_before = *n;
                self.last = Some(CellRun::Rows {
                    nulls_before,
                    source,
                    start: row,
                    len: 1,
                });
            }
            (_, None) => self.open(CellRun::Nulls(1)),
            (_, Some(Cell::Empty)) => self.open(CellRun::Empties(1)),
            (_, Some(Cell::Row { source, row })) => self.open(CellRun::Rows {
                nulls_before: 0,
                source,
                start: row,
                len: 1,
            }),
        }
    }

    /// Starts a new run after the current one.
    fn open(&mut self, run: CellRun) {
        if let Some(previous) = self.last.replace(run) {
            self.runs.push(previous);
        }
    }

    /// Writes the column's cells into `builder` as one finished column of its batch; the
    /// runs are cleared for the next batch.
    ///
    /// # Errors
    /// The batch's values would overflow the list's 32-bit offsets.
    pub fn finish(
        &mut self,
        sources: &Sources,
        builder: &mut ListColumnBuilder,
    ) -> Result<(), ArrowError> {
        self.len = 0;
        self.runs.extend(self.last.take());
        for run in self.runs.drain(..) {
            match run {
                CellRun::Nulls(n) => builder.repeat_offset(n as usize, false),
                CellRun::Empties(n) => builder.repeat_offset(n as usize, true),
                CellRun::Rows {
                    nulls_before,
                    source,
                    start,
                    len,
                } => {
                    builder.repeat_offset(nulls_before as usize, false);
                    builder.rows(sources, source, start, start + len);
                }
                CellRun::Repeat { source, row, times } => {
                    for _ in 0..times {
                        builder.row(sources, source, row);
                    }
                }
            }
        }
        builder.finish_column(sources)
    }
}
