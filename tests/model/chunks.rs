//! The chunks the model test builds: cells, rows, chunks as the test sees them, and their
//! encoding into (and decoding from) stored chunks.

use super::*;

/// A tree five levels deep, with a part that needs escaping and a gap (`e/f` holds nothing).
pub(crate) const ENTITIES: [&str; 9] = [
    "/", "a", "a/b", "a/b/c", "a/b/c/d", "a/d", "a/b\\ c", "e", "e/f/g",
];
/// `x`: `List<Float64>`; `s`: `List<Utf8>`; `p`: `List<FixedSizeList<Int32, 2>>`.
pub(crate) const COMPONENTS: [&str; 3] = ["x", "s", "p"];
pub(crate) const TIMELINES: [(&str, TimeType); 3] = [
    ("t1", TimeType::Sequence),
    ("t2", TimeType::DurationNs),
    ("t3", TimeType::TimestampNs),
];
pub(crate) const MAX_TIME: i64 = 12;
/// Where [`Op::Run`]s start and how far they reach at most: past the small times, so that
/// their chunks overlap nothing else.
pub(crate) const RUN_START: i64 = 100;
pub(crate) const RUN_END: i64 = RUN_START + 40 + 40 * 2;
/// Times at both ends of the valid range.
pub(crate) const EXTREMES: [i64; 4] = [i64::MIN + 1, i64::MIN + 2, i64::MAX - 1, i64::MAX];

/// A cell as the model sees it: `None` null, `Some(vec![])` empty, else instances.
pub(crate) type Cell = Option<Vec<i64>>;

/// What a row holds: data cells, or a Clear (recursive or not).
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Content {
    Data([Cell; 3]),
    Clear(bool),
}

/// One row of a chunk as the test builds it.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ModelRow {
    pub(crate) row_id: u128,
    /// The row's time on each timeline; only those of the chunk's timelines count.
    pub(crate) times: [i64; 3],
    pub(crate) content: Content,
}

/// A chunk as the test builds it: which timelines it has (bit `i`: `TIMELINES[i]`; none:
/// static) and whether it holds data or Clears.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct ModelChunk {
    pub(crate) id: ChunkId,
    pub(crate) entity: usize,
    pub(crate) timelines: u8,
    pub(crate) is_clear: bool,
    pub(crate) rows: Vec<ModelRow>,
}

impl ModelChunk {
    pub(crate) fn has_timeline(&self, timeline: usize) -> bool {
        self.timelines & (1 << timeline) != 0
    }

    pub(crate) fn is_static(&self) -> bool {
        self.timelines == 0
    }

    /// The row's time on `timeline`, if the chunk has that timeline.
    pub(crate) fn time(&self, row: &ModelRow, timeline: usize) -> Option<i64> {
        self.has_timeline(timeline).then_some(row.times[timeline])
    }

    /// The Arrow chunk.
    pub(crate) fn build(&self) -> Chunk {
        let row_ids = self
            .rows
            .iter()
            .map(|r| RowId::from_u128(r.row_id))
            .collect();
        let mut time_columns = Vec::new();
        for (i, (name, time_type)) in TIMELINES.iter().enumerate() {
            if self.has_timeline(i) {
                let times: Vec<i64> = self.rows.iter().map(|r| r.times[i]).collect();
                let array: ArrayRef = match time_type {
                    TimeType::Sequence => Arc::new(Int64Array::from(times)),
                    TimeType::DurationNs => {
                        Arc::new(PrimitiveArray::<DurationNanosecondType>::from(times))
                    }
                    TimeType::TimestampNs => {
                        Arc::new(PrimitiveArray::<TimestampNanosecondType>::from(times))
                    }
                };
                time_columns.push((Timeline::new(*name, *time_type), array));
            }
        }
        let components = if self.is_clear {
            let flags: Vec<Option<bool>> = self
                .rows
                .iter()
                .map(|r| match r.content {
                    Content::Clear(recursive) => Some(recursive),
                    Content::Data(_) => None,
                })
                .collect();
            vec![(ComponentName::CLEAR_IS_RECURSIVE.into(), bool_list(&flags))]
        } else {
            (0..COMPONENTS.len())
                .map(|c| {
                    let cells: Vec<Cell> = self
                        .rows
                        .iter()
                        .map(|r| match &r.content {
                            Content::Data(cells) => cells[c].clone(),
                            Content::Clear(_) => None,
                        })
                        .collect();
                    (COMPONENTS[c].into(), encode(c, &cells))
                })
                .collect()
        };
        Chunk::try_new(
            self.id,
            path(ENTITIES[self.entity]),
            row_ids,
            time_columns,
            components,
        )
        .unwrap()
    }
}

/// Component `c`'s column for `cells`: floats, strings or pairs `[v, -v]`.
pub(crate) fn encode(c: usize, cells: &[Cell]) -> ArrayRef {
    match c {
        0 => {
            let mut list = ListBuilder::new(Float64Builder::new());
            for cell in cells {
                for &v in cell.iter().flatten() {
                    list.values().append_value(v as f64);
                }
                list.append(cell.is_some());
            }
            Arc::new(list.finish())
        }
        1 => {
            let mut list = ListBuilder::new(StringBuilder::new());
            for cell in cells {
                for v in cell.iter().flatten() {
                    list.values().append_value(v.to_string());
                }
                list.append(cell.is_some());
            }
            Arc::new(list.finish())
        }
        _ => {
            let mut list = ListBuilder::new(FixedSizeListBuilder::new(Int32Builder::new(), 2));
            for cell in cells {
                for &v in cell.iter().flatten() {
                    let v = i32::try_from(v).unwrap();
                    list.values().values().append_value(v);
                    list.values().values().append_value(-v);
                    list.values().append(true);
                }
                list.append(cell.is_some());
            }
            Arc::new(list.finish())
        }
    }
}

/// The values of a cell of component `component`, as [`encode`] wrote them.
pub(crate) fn decode(component: &str, cell: &ArrayRef) -> Vec<i64> {
    match component {
        "x" => cell
            .as_primitive::<Float64Type>()
            .values()
            .iter()
            .map(|&v| v as i64)
            .collect(),
        "s" => cell
            .as_string::<i32>()
            .iter()
            .map(|v| v.unwrap().parse().unwrap())
            .collect(),
        _ => {
            let pairs = cell.as_fixed_size_list();
            let values = pairs.values().as_primitive::<Int32Type>();
            (0..pairs.len())
                .map(|i| {
                    let (v, minus) = (values.value(2 * i), values.value(2 * i + 1));
                    assert_eq!(minus, -v, "pairs are [v, -v]");
                    i64::from(v)
                })
                .collect()
        }
    }
}

/// A stored chunk as the test would have built it.
pub(crate) fn model_chunk_of(chunk: &Chunk) -> ModelChunk {
    let entity = ENTITIES
        .iter()
        .position(|e| path(e) == *chunk.entity_path())
        .unwrap();
    let rows: Vec<(u8, ModelRow)> = (0..chunk.num_rows())
        .map(|row| model_row_of(chunk, row))
        .collect();
    ModelChunk {
        id: chunk.id(),
        entity,
        timelines: rows.first().map_or(0, |(timelines, _)| *timelines),
        is_clear: chunk.component(ComponentName::CLEAR_IS_RECURSIVE).is_some(),
        rows: rows.into_iter().map(|(_, row)| row).collect(),
    }
}

/// Row `row` of a stored chunk as the model writes rows.
pub(crate) fn model_row_of(chunk: &Chunk, row: usize) -> (u8, ModelRow) {
    let mut timelines = 0;
    let mut times = [0; 3];
    for (i, (name, _)) in TIMELINES.iter().enumerate() {
        if let Some(column) = chunk.time_column(name) {
            timelines |= 1 << i;
            times[i] = column.times()[row];
        }
    }
    let content = match chunk.component(ComponentName::CLEAR_IS_RECURSIVE) {
        Some(column) => {
            let cell = column
                .cell(row)
                .expect("model Clear chunks have no null cell");
            Content::Clear(
                cell.as_any()
                    .downcast_ref::<BooleanArray>()
                    .unwrap()
                    .value(0),
            )
        }
        None => Content::Data(COMPONENTS.map(|name| {
            chunk
                .component(name)
                .and_then(|column| column.cell(row))
                .map(|cell| decode(name, &cell))
        })),
    };
    let row_id = chunk.row_ids()[row].as_u128();
    (
        timelines,
        ModelRow {
            row_id,
            times,
            content,
        },
    )
}
