//! What a Flight SQL statement carries between calls, in its handle and ticket, so that
//! the server keeps nothing per statement: the SQL text, the values bound to its
//! parameters (Flight SQL's stateless prepared statements: binding answers with a new
//! handle that holds them), and in a ticket the schema `GetFlightInfo` advertised.

use std::sync::Arc;

use arrow_array::RecordBatch;
use arrow_flight::IpcMessage;
use arrow_flight::SchemaAsIpc;
use arrow_ipc::writer::IpcWriteOptions;
use arrow_schema::{DataType, Field, Schema};
use datafusion::common::ScalarValue;
use datafusion::logical_expr::LogicalPlan;
use tonic::Status;

/// A statement: its SQL and, once bound, one value per parameter (in order).
#[derive(Debug, Clone, PartialEq)]
pub struct Statement {
    pub sql: String,
    pub parameters: Option<Vec<ScalarValue>>,
}

impl Statement {
    const MAGIC: &'static [u8] = b"chunkstore-prepared-1\0";

    /// A statement without bound values.
    pub fn new(sql: String) -> Self {
        Self {
            sql,
            parameters: None,
        }
    }

    /// The statement with `values` bound: the batch a client sent with `DoPut`, one row,
    /// a column per parameter.
    pub fn bound(self, values: &[RecordBatch]) -> Result<Self, Status> {
        let rows: usize = values.iter().map(RecordBatch::num_rows).sum();
        let Some(batch) = values.iter().find(|b| b.num_rows() > 0) else {
            return Ok(Self {
                parameters: None,
                ..self
            });
        };
        if rows != 1 {
            return Err(Status::invalid_argument(format!(
                "the parameters have {rows} rows: a query takes one row of values"
            )));
        }
        let parameters = batch
            .columns()
            .iter()
            .map(|column| ScalarValue::try_from_array(column, 0))
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| Status::invalid_argument(format!("reading the parameters: {e}")))?;
        Ok(Self {
            parameters: Some(parameters),
            ..self
        })
    }

    /// The handle that names this statement: its SQL alone, or with its values (as one
    /// row of Arrow IPC) after a marker.
    pub fn encode(&self) -> Result<Vec<u8>, Status> {
        let Some(parameters) = &self.parameters else {
            return Ok(self.sql.as_bytes().to_vec());
        };
        let columns = parameters
            .iter()
            .map(ScalarValue::to_array)
            .collect::<Result<Vec<_>, _>>()
            .map_err(|e| Status::internal(format!("encoding the parameters: {e}")))?;
        let fields: Vec<Field> = columns
            .iter()
            .enumerate()
            .map(|(i, c)| Field::new(format!("${}", i + 1), c.data_type().clone(), true))
            .collect();
        let options = arrow_array::RecordBatchOptions::new().with_row_count(Some(1));
        let batch =
            RecordBatch::try_new_with_options(Arc::new(Schema::new(fields)), columns, &options)
                .map_err(|e| Status::internal(format!("encoding the parameters: {e}")))?;
        let schema = batch.schema();
        let mut values = Vec::new();
        let reader = arrow_array::RecordBatchIterator::new([Ok(batch)], schema);
        chunkstore::ipc::write_ipc_stream(&mut values, reader)
            .map_err(|e| Status::internal(format!("encoding the parameters: {e}")))?;
        Ok(length_prefixed_after(
            Self::MAGIC,
            &values,
            self.sql.as_bytes(),
        ))
    }

    /// The statement a handle names (see [`Statement::encode`]).
    pub fn decode(handle: &[u8]) -> Result<Self, Status> {
        let Some(rest) = handle.strip_prefix(Self::MAGIC) else {
            return Ok(Self::new(utf8(handle, "the statement handle")?));
        };
        let bad = || Status::invalid_argument("the statement handle is malformed");
        let (values, sql) = length_prefixed(rest).ok_or_else(bad)?;
        let batches = chunkstore::ipc::read_batches(values).map_err(|_| bad())?;
        Self::new(utf8(sql, "the statement handle")?).bound(&batches)
    }

    /// The SQL to plan: each `?` (the placeholder JDBC, ODBC and ADBC users write)
    /// numbered as `$1`, `$2`, ... in order, which DataFusion binds by position; `$n`
    /// placeholders are left as they are.
    pub fn numbered_sql(&self) -> String {
        numbered_placeholders(&self.sql)
    }
}

/// `sql` with each `?` placeholder (outside literals, identifiers and comments) numbered.
fn numbered_placeholders(sql: &str) -> String {
    use datafusion::sql::sqlparser::dialect::GenericDialect;
    use datafusion::sql::sqlparser::tokenizer::{Token, Tokenizer};

    if !sql.contains('?') {
        return sql.to_owned();
    }
    let Ok(tokens) = Tokenizer::new(&GenericDialect {}, sql).tokenize() else {
        return sql.to_owned(); // the planner says what is wrong
    };
    if !tokens
        .iter()
        .any(|t| matches!(t, Token::Placeholder(p) if p == "?"))
    {
        return sql.to_owned();
    }
    let mut next = 0;
    tokens
        .into_iter()
        .map(|token| match token {
            Token::Placeholder(p) if p == "?" => {
                next += 1;
                format!("${next}")
            }
            other => other.to_string(),
        })
        .collect()
}

/// The schema of a plan's parameters, for `CreatePreparedStatement`: a field per
/// placeholder, by position, of the type planning inferred (`Null` where it could not).
pub fn parameter_schema(plan: &LogicalPlan) -> Result<Schema, Status> {
    let types = plan
        .get_parameter_types()
        .map_err(|e| Status::invalid_argument(e.to_string().replace('\n', " ")))?;
    let mut named: Vec<(usize, String, DataType)> = types
        .into_iter()
        .map(|(id, data_type)| {
            let position = id
                .strip_prefix('$')
                .and_then(|n| n.parse::<usize>().ok())
                .unwrap_or(usize::MAX);
            (position, id, data_type.unwrap_or(DataType::Null))
        })
        .collect();
    named.sort();
    Ok(Schema::new(
        named
            .into_iter()
            .map(|(_, id, data_type)| Field::new(id, data_type, true))
            .collect::<Vec<_>>(),
    ))
}

/// A statement's ticket: the schema `GetFlightInfo` advertised, then the statement's
/// handle, so that `DoGet` sends what was advertised.
pub struct StatementTicket;

impl StatementTicket {
    const MAGIC: &'static [u8] = b"chunkstore-ticket-1\0";

    pub fn encode(schema: &Schema, statement: &Statement) -> Result<Vec<u8>, Status> {
        Ok(length_prefixed_after(
            Self::MAGIC,
            &schema_bytes(schema)?,
            &statement.encode()?,
        ))
    }

    /// The statement and the advertised schema; a ticket that is plain SQL has no schema.
    pub fn decode(ticket: &[u8]) -> Result<(Statement, Option<Arc<Schema>>), Status> {
        let Some(rest) = ticket.strip_prefix(Self::MAGIC) else {
            return Ok((Statement::new(utf8(ticket, "the statement ticket")?), None));
        };
        let bad = || Status::invalid_argument("the statement ticket is malformed");
        let (schema_bytes, handle) = length_prefixed(rest).ok_or_else(bad)?;
        let schema = Schema::try_from(IpcMessage(bytes::Bytes::copy_from_slice(schema_bytes)))
            .map_err(|_| bad())?;
        Ok((Statement::decode(handle)?, Some(Arc::new(schema))))
    }
}

/// `schema` as a Flight IPC schema message.
pub fn schema_bytes(schema: &Schema) -> Result<bytes::Bytes, Status> {
    let IpcMessage(bytes) = SchemaAsIpc::new(schema, &IpcWriteOptions::default())
        .try_into()
        .map_err(|e: arrow_schema::ArrowError| {
            Status::internal(format!("encoding the schema: {e}"))
        })?;
    Ok(bytes)
}

/// `magic`, then `part` after its length (8 bytes, little-endian), then `rest`: what
/// [`length_prefixed`] splits after the magic.
fn length_prefixed_after(magic: &[u8], part: &[u8], rest: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(magic.len() + 8 + part.len() + rest.len());
    out.extend_from_slice(magic);
    out.extend_from_slice(&(part.len() as u64).to_le_bytes());
    out.extend_from_slice(part);
    out.extend_from_slice(rest);
    out
}

/// `bytes` split after a part whose length (8 bytes, little-endian) comes first.
fn length_prefixed(bytes: &[u8]) -> Option<(&[u8], &[u8])> {
    let (len, rest) = bytes.split_at_checked(8)?;
    let len = usize::try_from(u64::from_le_bytes(len.try_into().ok()?)).ok()?;
    rest.split_at_checked(len)
}

pub fn utf8(bytes: &[u8], what: &str) -> Result<String, Status> {
    String::from_utf8(bytes.to_vec())
        .map_err(|_| Status::invalid_argument(format!("{what} is not UTF-8")))
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use arrow_array::{Int64Array, RecordBatch, StringArray};
    use arrow_schema::{DataType, Field, Schema};
    use datafusion::common::ScalarValue;

    use super::{Statement, StatementTicket, numbered_placeholders};

    #[test]
    fn question_marks_are_numbered_outside_literals_and_comments() {
        assert_eq!(
            numbered_placeholders("SELECT '?', \"a?\" FROM t WHERE x > ? AND y = ? -- ?"),
            "SELECT '?', \"a?\" FROM t WHERE x > $1 AND y = $2 -- ?"
        );
        assert_eq!(numbered_placeholders("SELECT $1"), "SELECT $1");
        assert_eq!(numbered_placeholders("SELECT '?'"), "SELECT '?'");
    }

    #[test]
    fn a_bound_statement_round_trips_through_its_handle_and_ticket() {
        let values = RecordBatch::try_new(
            Arc::new(Schema::new(vec![
                Field::new("a", DataType::Int64, true),
                Field::new("b", DataType::Utf8, true),
            ])),
            vec![
                Arc::new(Int64Array::from(vec![42])),
                Arc::new(StringArray::from(vec!["/robot"])),
            ],
        )
        .unwrap();
        let statement = Statement::new("SELECT ? + 1, ?".to_owned())
            .bound(&[values])
            .unwrap();
        assert_eq!(
            statement.parameters,
            Some(vec![
                ScalarValue::Int64(Some(42)),
                ScalarValue::Utf8(Some("/robot".to_owned()))
            ])
        );
        let handle = statement.encode().unwrap();
        assert_eq!(Statement::decode(&handle).unwrap(), statement);
        let schema = Schema::new(vec![Field::new("x", DataType::Int64, true)]);
        let (decoded, advertised) =
            StatementTicket::decode(&StatementTicket::encode(&schema, &statement).unwrap())
                .unwrap();
        assert_eq!(decoded, statement);
        assert_eq!(advertised.as_deref(), Some(&schema));
        // Unbound, the handle is the SQL itself.
        assert_eq!(
            Statement::new("SELECT 1".to_owned()).encode().unwrap(),
            b"SELECT 1"
        );
    }

    #[test]
    fn two_rows_of_values_and_damaged_handles_are_refused() {
        let two = RecordBatch::try_new(
            Arc::new(Schema::new(vec![Field::new("a", DataType::Int64, true)])),
            vec![Arc::new(Int64Array::from(vec![1, 2]))],
        )
        .unwrap();
        let error = Statement::new("SELECT ?".to_owned())
            .bound(&[two])
            .unwrap_err();
        assert!(error.message().contains("2 rows"), "{error}");
        let mut handle = b"chunkstore-prepared-1\0".to_vec();
        handle.extend_from_slice(&u64::MAX.to_le_bytes());
        assert!(Statement::decode(&handle).is_err());
        handle.truncate(handle.len() - 8);
        handle.extend_from_slice(&3u64.to_le_bytes());
        handle.extend_from_slice(b"abcSELECT 1");
        assert!(Statement::decode(&handle).is_err());
    }
}
