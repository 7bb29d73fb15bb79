//! Arrow types as Delta Lake types: what a table's schema says of a column, and the Arrow
//! type its files hold so that every Delta reader finds exactly that type.
//!
//! Delta has no unsigned integers, no nanosecond timestamps, no fixed-size lists and no
//! durations. Each becomes the Delta type that holds every value exactly (SEMANTICS.md
//! section 15): `u8` -> `short`, `u16` -> `integer`, `u32` -> `long`, `u64` ->
//! `decimal(20,0)` (as Spark reads unsigned Parquet columns); timestamps, durations and
//! times of day -> `long` in their own unit (Rerun's are nanoseconds, since the Unix epoch
//! for timestamps), the unit in the field's `comment`; fixed-size lists -> `array`, fixed-
//! size binary (row and chunk ids) -> `binary`; a dictionary -> its values' type.

use std::sync::Arc;

use arrow_array::{RecordBatch, RecordBatchReader};
use arrow_schema::{ArrowError, DataType, Field, Fields, Schema, SchemaRef, TimeUnit};
use serde_json::{Value, json};

/// A column a Delta table cannot hold: `Unrepresentable::UnsupportedType` and
/// `Unrepresentable::ColumnName` say it to the user.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Unrepresentable {
    /// A type Delta has none for.
    Type {
        /// The top-level column.
        column: String,
        /// Its Arrow type.
        data_type: String,
    },
    /// A name Delta cannot hold.
    Name {
        /// The top-level column.
        column: String,
    },
}

impl std::fmt::Display for Unrepresentable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Type { column, data_type } => write!(
                f,
                "column {column:?}: Delta has no type for Arrow's {data_type}"
            ),
            Self::Name { column } => write!(
                f,
                "column {column:?}: a Delta column name cannot be empty or hold any of \
                 ' ,;{{}}()\\n\\t='"
            ),
        }
    }
}

/// The characters a Delta column name cannot hold without column mapping (Spark's Parquet
/// rule, which Delta keeps).
const FORBIDDEN_IN_NAMES: &[char] = &[' ', ',', ';', '{', '}', '(', ')', '\n', '\t', '='];

/// A table's columns as Delta sees them, and the Arrow schema its files are written in.
#[derive(Clone, Debug)]
pub(crate) struct DeltaSchema {
    /// The schema's fields as Delta's JSON schema writes them (`{"name", "type",
    /// "nullable", "metadata"}`), in the files' order.
    pub fields: Vec<Value>,
    /// What the files hold: the source's columns cast to the Delta types' Arrow types.
    pub arrow: SchemaRef,
}

impl DeltaSchema {
    /// The Delta schema of files with `schema`'s columns.
    ///
    /// # Errors
    /// [`Unrepresentable::Type`] for a type Delta cannot hold (a union, a decimal wider
    /// than 38 digits), [`Unrepresentable::Name`] for a name it cannot hold.
    pub fn of(schema: &Schema) -> Result<Self, Unrepresentable> {
        let mut fields = Vec::with_capacity(schema.fields().len());
        let mut arrow = Vec::with_capacity(schema.fields().len());
        for field in schema.fields() {
            let (typed, json) = delta_field(field, field.name())?;
            fields.push(json);
            arrow.push(typed);
        }
        Ok(Self {
            fields,
            arrow: Arc::new(Schema::new(arrow)),
        })
    }
}

/// `field` as a Delta field: its Arrow field in the files, and its JSON. `column` names
/// the top-level column in errors.
fn delta_field(field: &Field, column: &str) -> Result<(Field, Value), Unrepresentable> {
    if field.name().contains(FORBIDDEN_IN_NAMES) || field.name().is_empty() {
        return Err(Unrepresentable::Name {
            column: column.to_owned(),
        });
    }
    let (data_type, json_type) = delta_type(field.data_type(), column)?;
    let mut metadata = serde_json::Map::new();
    if let Some(comment) = unit_comment(field.data_type()) {
        metadata.insert("comment".into(), Value::String(comment));
    }
    let json = json!({
        "name": field.name(),
        "type": json_type,
        "nullable": field.is_nullable(),
        "metadata": metadata,
    });
    Ok((
        Field::new(field.name(), data_type, field.is_nullable()),
        json,
    ))
}

/// What a `long` that was a time holds, for its field's comment.
fn unit_comment(data_type: &DataType) -> Option<String> {
    let unit = |unit: &TimeUnit| match unit {
        TimeUnit::Second => "seconds",
        TimeUnit::Millisecond => "milliseconds",
        TimeUnit::Microsecond => "microseconds",
        TimeUnit::Nanosecond => "nanoseconds",
    };
    match data_type {
        DataType::Timestamp(u, _) => Some(format!("{} since the Unix epoch", unit(u))),
        DataType::Duration(u) => Some(format!("a duration in {}", unit(u))),
        DataType::Time32(u) | DataType::Time64(u) => Some(format!("a time of day in {}", unit(u))),
        _ => None,
    }
}

/// The Arrow type a file holds for `data_type`, and its Delta type.
fn delta_type(data_type: &DataType, column: &str) -> Result<(DataType, Value), Unrepresentable> {
    use DataType as T;
    let primitive = |arrow: DataType, delta: &str| Ok((arrow, Value::String(delta.into())));
    match data_type {
        T::Boolean => primitive(T::Boolean, "boolean"),
        T::Int8 => primitive(T::Int8, "byte"),
        T::Int16 | T::UInt8 => primitive(T::Int16, "short"),
        T::Int32 | T::UInt16 | T::Time32(_) => primitive(T::Int32, "integer"),
        T::Int64 | T::UInt32 | T::Timestamp(..) | T::Duration(_) | T::Time64(_) => {
            primitive(T::Int64, "long")
        }
        T::UInt64 => primitive(T::Decimal128(20, 0), "decimal(20,0)"),
        T::Float16 | T::Float32 => primitive(T::Float32, "float"),
        T::Float64 => primitive(T::Float64, "double"),
        // A column of nulls only: a nullable string.
        T::Null | T::Utf8 | T::LargeUtf8 | T::Utf8View => primitive(T::Utf8, "string"),
        T::Binary | T::LargeBinary | T::BinaryView | T::FixedSizeBinary(_) => {
            primitive(T::Binary, "binary")
        }
        T::Date32 | T::Date64 => primitive(T::Date32, "date"),
        T::Decimal32(p, s) | T::Decimal64(p, s) => Ok(decimal(*p, *s)),
        T::Decimal128(p, s) | T::Decimal256(p, s) if *p <= 38 => Ok(decimal(*p, *s)),
        T::List(item)
        | T::LargeList(item)
        | T::ListView(item)
        | T::LargeListView(item)
        | T::FixedSizeList(item, _) => {
            let (element, element_type) = delta_type(item.data_type(), column)?;
            Ok((
                T::List(Arc::new(Field::new_list_field(element, item.is_nullable()))),
                json!({
                    "type": "array",
                    "elementType": element_type,
                    "containsNull": item.is_nullable(),
                }),
            ))
        }
        T::Struct(fields) => {
            let mut arrow = Vec::with_capacity(fields.len());
            let mut json = Vec::with_capacity(fields.len());
            for field in fields {
                let (typed, field_json) = delta_field(field, column)?;
                arrow.push(typed);
                json.push(field_json);
            }
            Ok((
                T::Struct(Fields::from(arrow)),
                json!({ "type": "struct", "fields": json }),
            ))
        }
        T::Map(entries, sorted) => {
            let T::Struct(kv) = entries.data_type() else {
                return unsupported(data_type, column);
            };
            let [key, value] = kv.iter().collect::<Vec<_>>()[..] else {
                return unsupported(data_type, column);
            };
            let (key_type, key_json) = delta_type(key.data_type(), column)?;
            let (value_type, value_json) = delta_type(value.data_type(), column)?;
            let entries = Field::new(
                entries.name(),
                T::Struct(Fields::from(vec![
                    Field::new(key.name(), key_type, false),
                    Field::new(value.name(), value_type, value.is_nullable()),
                ])),
                false,
            );
            Ok((
                T::Map(Arc::new(entries), *sorted),
                json!({
                    "type": "map",
                    "keyType": key_json,
                    "valueType": value_json,
                    "valueContainsNull": value.is_nullable(),
                }),
            ))
        }
        T::Dictionary(_, values) => delta_type(values, column),
        _ => unsupported(data_type, column),
    }
}

fn decimal(precision: u8, scale: i8) -> (DataType, Value) {
    (
        DataType::Decimal128(precision, scale),
        Value::String(format!("decimal({precision},{scale})")),
    )
}

fn unsupported<T>(data_type: &DataType, column: &str) -> Result<T, Unrepresentable> {
    Err(Unrepresentable::Type {
        column: column.to_owned(),
        data_type: data_type.to_string(),
    })
}

/// A reader's batches cast to a [`DeltaSchema`]'s Arrow schema, for the Parquet writer.
pub(crate) struct DeltaTyped<R> {
    inner: R,
    schema: SchemaRef,
}

impl<R: RecordBatchReader> DeltaTyped<R> {
    /// `inner`'s batches as a Delta table's files hold them.
    ///
    /// # Errors
    /// As [`DeltaSchema::of`] for `inner`'s schema.
    pub fn new(inner: R) -> Result<Self, Unrepresentable> {
        let schema = DeltaSchema::of(&inner.schema())?.arrow;
        Ok(Self { inner, schema })
    }
}

impl<R: RecordBatchReader> Iterator for DeltaTyped<R> {
    type Item = Result<RecordBatch, ArrowError>;

    fn next(&mut self) -> Option<Self::Item> {
        let batch = match self.inner.next()? {
            Ok(batch) => batch,
            Err(error) => return Some(Err(error)),
        };
        let columns: Result<Vec<_>, ArrowError> = batch
            .columns()
            .iter()
            .zip(self.schema.fields())
            .map(|(column, field)| arrow_cast::cast(column, field.data_type()))
            .collect();
        Some(columns.and_then(|columns| RecordBatch::try_new(Arc::clone(&self.schema), columns)))
    }
}

impl<R: RecordBatchReader> RecordBatchReader for DeltaTyped<R> {
    fn schema(&self) -> SchemaRef {
        Arc::clone(&self.schema)
    }
}

#[cfg(test)]
mod tests {
    use arrow_array::{
        Array, ArrayRef, Decimal128Array, FixedSizeListArray, Float32Array, Int16Array, Int64Array,
        ListArray, RecordBatchIterator, TimestampNanosecondArray, UInt8Array, UInt64Array,
        UnionArray,
    };
    use arrow_buffer::ScalarBuffer;
    use arrow_schema::UnionFields;

    use super::*;

    fn field_type(schema: &DeltaSchema, name: &str) -> Value {
        schema
            .fields
            .iter()
            .find(|f| f["name"] == name)
            .map_or(Value::Null, |f| f["type"].clone())
    }

    /// Each Arrow type becomes the Delta type that holds all its values, and the files'
    /// Arrow type is that Delta type's.
    #[test]
    fn every_rerun_type_has_a_delta_type_holding_its_values() {
        let xyz =
            DataType::FixedSizeList(Arc::new(Field::new_list_field(DataType::Float32, false)), 3);
        let schema = Schema::new(vec![
            Field::new("u8", DataType::UInt8, true),
            Field::new("u16", DataType::UInt16, true),
            Field::new("u32", DataType::UInt32, false),
            Field::new("u64", DataType::UInt64, true),
            Field::new("t", DataType::Timestamp(TimeUnit::Nanosecond, None), true),
            Field::new("d", DataType::Duration(TimeUnit::Nanosecond), true),
            Field::new("id", DataType::FixedSizeBinary(16), false),
            Field::new("xyz", xyz.clone(), true),
            Field::new(
                "s",
                DataType::Struct(Fields::from(vec![
                    Field::new("axis", xyz, false),
                    Field::new("w", DataType::UInt32, false),
                ])),
                true,
            ),
            Field::new(
                "dict",
                DataType::Dictionary(Box::new(DataType::Int32), Box::new(DataType::Utf8)),
                true,
            ),
            Field::new("f16", DataType::Float16, true),
        ]);
        let delta = DeltaSchema::of(&schema).unwrap();
        assert_eq!(field_type(&delta, "u8"), "short");
        assert_eq!(field_type(&delta, "u16"), "integer");
        assert_eq!(field_type(&delta, "u32"), "long");
        assert_eq!(field_type(&delta, "u64"), "decimal(20,0)");
        assert_eq!(field_type(&delta, "t"), "long");
        assert_eq!(field_type(&delta, "d"), "long");
        assert_eq!(field_type(&delta, "id"), "binary");
        assert_eq!(
            field_type(&delta, "xyz"),
            json!({"type": "array", "elementType": "float", "containsNull": false})
        );
        assert_eq!(
            field_type(&delta, "s")["fields"][0]["type"]["type"],
            "array"
        );
        assert_eq!(field_type(&delta, "s")["fields"][1]["type"], "long");
        assert_eq!(field_type(&delta, "dict"), "string");
        assert_eq!(field_type(&delta, "f16"), "float");
        let t = delta.fields.iter().find(|f| f["name"] == "t").unwrap();
        assert_eq!(t["metadata"]["comment"], "nanoseconds since the Unix epoch");
        assert_eq!(t["nullable"], true);
        let u32_field = delta.fields.iter().find(|f| f["name"] == "u32").unwrap();
        assert_eq!(u32_field["nullable"], false);
        assert_eq!(delta.arrow.field(0).data_type(), &DataType::Int16);
        assert_eq!(
            delta.arrow.field(3).data_type(),
            &DataType::Decimal128(20, 0)
        );
    }

    /// Casting keeps every value: the largest `u64`, nanosecond timestamps, `u8` lists.
    #[test]
    fn cast_batches_keep_every_value() {
        let points = FixedSizeListArray::new(
            Arc::new(Field::new_list_field(DataType::Float32, false)),
            3,
            Arc::new(Float32Array::from(vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0])),
            None,
        );
        let bytes = ListArray::new(
            Arc::new(Field::new_list_field(DataType::UInt8, false)),
            arrow_buffer::OffsetBuffer::new(ScalarBuffer::from(vec![0, 2, 3])),
            Arc::new(UInt8Array::from(vec![0, 255, 128])),
            None,
        );
        let columns: Vec<ArrayRef> = vec![
            Arc::new(UInt64Array::from(vec![u64::MAX, 0])),
            Arc::new(TimestampNanosecondArray::from(vec![
                1_795_265_748_902_914_462,
                -1,
            ])),
            Arc::new(points),
            Arc::new(bytes),
        ];
        let schema = Arc::new(Schema::new(vec![
            Field::new("u64", columns[0].data_type().clone(), false),
            Field::new("t", columns[1].data_type().clone(), false),
            Field::new("xyz", columns[2].data_type().clone(), false),
            Field::new("buffer", columns[3].data_type().clone(), false),
        ]));
        let batch = RecordBatch::try_new(Arc::clone(&schema), columns).unwrap();
        let reader = RecordBatchIterator::new([Ok(batch)], schema);
        let mut typed = DeltaTyped::new(reader).unwrap();
        let out = typed.next().unwrap().unwrap();
        let big = out
            .column(0)
            .as_any()
            .downcast_ref::<Decimal128Array>()
            .unwrap();
        assert_eq!(big.value(0), i128::from(u64::MAX));
        let times = out.column(1).as_any().downcast_ref::<Int64Array>().unwrap();
        assert_eq!(times.values().to_vec(), [1_795_265_748_902_914_462, -1]);
        let xyz = out.column(2).as_any().downcast_ref::<ListArray>().unwrap();
        assert_eq!(xyz.value_length(1), 3);
        let buffer = out.column(3).as_any().downcast_ref::<ListArray>().unwrap();
        let values = buffer
            .values()
            .as_any()
            .downcast_ref::<Int16Array>()
            .unwrap();
        assert_eq!(values.values().to_vec(), [0, 255, 128]);
        assert!(typed.next().is_none());
    }

    /// What Delta cannot hold is an error naming the column: a union, a name with a space
    /// or `=` (in a struct too).
    #[test]
    fn a_type_or_name_delta_cannot_hold_names_its_column() {
        let union = UnionArray::try_new(
            UnionFields::try_new([0], [Field::new("a", DataType::Int32, true)]).unwrap(),
            ScalarBuffer::from(vec![0_i8]),
            None,
            vec![Arc::new(arrow_array::Int32Array::from(vec![1])) as ArrayRef],
        )
        .unwrap();
        let schema = Schema::new(vec![Field::new("u", union.data_type().clone(), true)]);
        let error = DeltaSchema::of(&schema).unwrap_err();
        assert!(
            matches!(&error, Unrepresentable::Type { column, .. } if column == "u"),
            "{error}"
        );
        for (name, inner) in [("a b", "x"), ("s", "k=v")] {
            let schema = Schema::new(vec![Field::new(
                name,
                DataType::Struct(Fields::from(vec![Field::new(inner, DataType::Int8, true)])),
                true,
            )]);
            let error = DeltaSchema::of(&schema).unwrap_err();
            assert!(
                matches!(&error, Unrepresentable::Name { column } if column == name),
                "{name}: {error}"
            );
        }
    }
}
