//! Arrow Flight SQL over the hub's recordings: the tables of `chunkstore sql`, stacked
//! across recordings with `rerun_segment_id` first ([`chunkstore::sql::register_segments`]).
//! Every query plans and runs on snapshots taken when it starts, so ingest goes on.
//!
//! A statement's ticket and a prepared statement's handle carry the statement itself
//! (`statement.rs`: its SQL, its bound values, the schema it advertised): the server keeps
//! no per-query state, and `DoGet` runs the query on the snapshots of that moment.
//! Flight SQL's metadata calls answer with one catalog (`datafusion`) and one schema
//! (`public`), DataFusion's defaults, so that qualified names work too.

use std::pin::Pin;
use std::sync::{Arc, OnceLock};

use arrow_flight::decode::FlightRecordBatchStream;
use arrow_flight::encode::FlightDataEncoderBuilder;
use arrow_flight::error::FlightError;
use arrow_flight::sql::metadata::{SqlInfoData, SqlInfoDataBuilder};
use arrow_flight::sql::server::FlightSqlService;
use arrow_flight::sql::server::PeekableFlightDataStream;
use arrow_flight::sql::{
    ActionClosePreparedStatementRequest, ActionCreatePreparedStatementRequest,
    ActionCreatePreparedStatementResult, CommandGetCatalogs, CommandGetDbSchemas,
    CommandGetSqlInfo, CommandGetTableTypes, CommandGetTables, CommandPreparedStatementQuery,
    CommandStatementQuery, DoPutPreparedStatementResult, ProstMessageExt as _, SqlInfo,
    TicketStatementQuery,
};
use arrow_flight::{FlightDescriptor, FlightEndpoint, FlightInfo, Ticket};
use arrow_schema::Schema;
use datafusion::prelude::SessionContext;
use futures::{Stream, StreamExt as _, TryStreamExt as _};
use prost::Message as _;
use tonic::{Request, Response, Status};

use super::statement::{Statement, StatementTicket, parameter_schema, schema_bytes};
use super::{ServerState, recordings};

/// Flight's gRPC service name (Flight SQL is carried in it).
pub const SERVICE: &str = <arrow_flight::flight_service_server::FlightServiceServer<SqlService> as tonic::server::NamedService>::NAME;

const CATALOG: &str = "datafusion";
const SCHEMA: &str = "public";

type DoGetStream = Pin<Box<dyn Stream<Item = Result<arrow_flight::FlightData, Status>> + Send>>;

/// The Flight SQL service.
pub struct SqlService {
    state: Arc<ServerState>,
    /// The runtime queries plan and run on, apart from the one serving connections.
    queries: tokio::runtime::Handle,
}

impl SqlService {
    pub fn new(state: Arc<ServerState>, queries: tokio::runtime::Handle) -> Self {
        Self { state, queries }
    }

    /// A query context over the recordings as they are now
    /// ([`super::session::QuerySessions::current`]).
    fn session(&self) -> Result<SessionContext, Status> {
        self.state
            .query_sessions
            .current(&self.state.hub, &self.state.metrics)
            .map_err(query_error)
    }

    /// Runs `work` on the query runtime: DataFusion's planning and execution are CPU work
    /// without a pause (planning is quadratic in a table's columns, apache/datafusion#7698),
    /// and on the connections' runtime a wide `SELECT *` left the server deaf to every
    /// other call.
    async fn on_queries<T: Send + 'static>(
        &self,
        work: impl std::future::Future<Output = Result<T, Status>> + Send + 'static,
    ) -> Result<T, Status> {
        self.queries
            .spawn(work)
            .await
            .map_err(|e| Status::internal(format!("planning failed: {e}")))?
    }

    /// Plans `statement` on the recordings as of now (the logical plan), its values
    /// bound where it has them.
    async fn plan(
        &self,
        statement: &Statement,
    ) -> Result<datafusion::dataframe::DataFrame, Status> {
        let ctx = self.session()?;
        let statement = statement.clone();
        let state = Arc::clone(&self.state);
        self.on_queries(async move {
            // Queries only: contexts are shared between clients, and the tables are the
            // recordings (nothing to create, insert into or set).
            let read_only = datafusion::execution::context::SQLOptions::new()
                .with_allow_ddl(false)
                .with_allow_dml(false)
                .with_allow_statements(false);
            let frame = ctx
                .sql_with_options(&statement.numbered_sql(), read_only)
                .await
                .map_err(|error| {
                    unknown_table_named(&ctx, &error).unwrap_or_else(|| query_error(error))
                })?;
            match statement.parameters {
                Some(values) => frame.with_param_values(values).map_err(query_error),
                None => Ok(frame),
            }
        })
        .await
        .inspect_err(|_| state.metrics.query_failed())
    }

    async fn statement_info(
        &self,
        statement: &Statement,
        descriptor: FlightDescriptor,
    ) -> Result<Response<FlightInfo>, Status> {
        let schema = self.plan(statement).await?.schema().as_arrow().clone();
        let ticket = TicketStatementQuery {
            statement_handle: StatementTicket::encode(&schema, statement)?.into(),
        };
        let endpoint = FlightEndpoint::new().with_ticket(Ticket {
            ticket: ticket.as_any().encode_to_vec().into(),
        });
        let info = FlightInfo::new()
            .try_with_schema(&schema)
            .map_err(|e| Status::internal(format!("encoding the schema: {e}")))?
            .with_endpoint(endpoint)
            .with_descriptor(descriptor)
            .with_ordered(true);
        Ok(Response::new(info))
    }

    /// Runs `sql` on the recordings as of now; with the schema `GetFlightInfo` advertised,
    /// its batches are put in that schema (ingest between the two calls may have added
    /// columns to `SELECT *`, or a collection dropped some).
    async fn run(
        &self,
        statement: &Statement,
        advertised: Option<Arc<Schema>>,
    ) -> Result<Response<DoGetStream>, Status> {
        let sql = &statement.sql;
        let started = std::time::Instant::now();
        let mut planning = Abandoned::new(sql, "while it was planned");
        // A plan that fails is counted by `plan`.
        let frame = self.plan(statement).await?;
        let planned = Arc::new(frame.schema().as_arrow().clone());
        let (plan, task) = self
            .on_queries(async move {
                let task = Arc::new(frame.task_ctx());
                let plan = frame.create_physical_plan().await.map_err(query_error)?;
                Ok((plan, task))
            })
            .await
            .inspect_err(|_| self.state.metrics.query_failed())?;
        planning.finished = true;
        // Run on a task of its own, batches handed over through a small channel: an
        // operator that computes for minutes inside one poll (an aggregate over a cross
        // join) would otherwise hold the connection's task, which then never sees the
        // client go. The task is aborted when the stream is dropped.
        let (sender, receiver) = tokio::sync::mpsc::channel(2);
        // Executed there too: DataFusion spawns a plan's partitions on the runtime that
        // calls `execute`.
        let producer = self.queries.spawn(async move {
            let mut batches = match datafusion::physical_plan::execute_stream(plan, task) {
                Ok(batches) => batches,
                Err(error) => {
                    let _ = sender.send(Err(error)).await;
                    return;
                }
            };
            while let Some(batch) = batches.next().await {
                if sender.send(batch).await.is_err() {
                    return;
                }
            }
        });
        let batches = Watched {
            inner: tokio_stream::wrappers::ReceiverStream::new(receiver),
            abandoned: Abandoned::new(sql, "before the query's end"),
            producer,
            batches: 0,
            state: Arc::clone(&self.state),
            started,
            failed: false,
        };
        let (schema, batches): (_, DoGetBatches) = match advertised {
            Some(advertised) if advertised.fields() != planned.fields() => {
                let target = Arc::clone(&advertised);
                let placed = batches.map_err(|e| FlightError::ExternalError(Box::new(e)));
                let placed = placed.and_then(move |batch| {
                    let target = Arc::clone(&target);
                    async move { place_in(&batch, &target).map_err(FlightError::Arrow) }
                });
                (advertised, Box::pin(placed))
            }
            _ => (
                planned,
                Box::pin(batches.map_err(|e| FlightError::ExternalError(Box::new(e)))),
            ),
        };
        let stream = FlightDataEncoderBuilder::new()
            .with_schema(schema)
            .build(batches)
            .map_err(Status::from);
        Ok(Response::new(Box::pin(stream)))
    }
}

/// Says, when dropped unfinished, that a query's client left (a dropped call or stream
/// stops the query: DataFusion's tasks end with their stream).
struct Abandoned {
    sql: String,
    when: &'static str,
    finished: bool,
}

impl Abandoned {
    fn new(sql: &str, when: &'static str) -> Self {
        Self {
            sql: sql.chars().take(80).collect(),
            when,
            finished: false,
        }
    }
}

impl Drop for Abandoned {
    fn drop(&mut self) {
        if !self.finished {
            tracing::info!(
                "query stopped: its client left {} ({})",
                self.when,
                self.sql
            );
        }
    }
}

/// A query's batches as they are sent.
struct Watched {
    inner:
        tokio_stream::wrappers::ReceiverStream<datafusion::error::Result<arrow_array::RecordBatch>>,
    abandoned: Abandoned,
    /// The task that runs the query.
    producer: tokio::task::JoinHandle<()>,
    batches: u64,
    /// Where the query's latency and failure are counted.
    state: Arc<ServerState>,
    started: std::time::Instant,
    failed: bool,
}

impl Drop for Watched {
    fn drop(&mut self) {
        self.producer.abort();
    }
}

impl Stream for Watched {
    type Item = datafusion::error::Result<arrow_array::RecordBatch>;

    fn poll_next(
        mut self: Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<Option<Self::Item>> {
        let polled = Pin::new(&mut self.inner).poll_next(cx);
        match &polled {
            std::task::Poll::Ready(None) => {
                self.abandoned.finished = true;
                if !self.failed {
                    self.state.metrics.queries.observe(self.started.elapsed());
                }
            }
            std::task::Poll::Ready(Some(Err(_))) => {
                self.failed = true;
                self.state.metrics.query_failed();
            }
            std::task::Poll::Ready(Some(Ok(_))) => self.batches += 1,
            std::task::Poll::Pending => {}
        }
        polled
    }
}

type DoGetBatches =
    Pin<Box<dyn Stream<Item = Result<arrow_array::RecordBatch, FlightError>> + Send>>;

/// `batch`'s columns in `schema`, by name: a column it lacks is null, one of another type
/// is cast.
fn place_in(
    batch: &arrow_array::RecordBatch,
    schema: &Arc<Schema>,
) -> Result<arrow_array::RecordBatch, arrow_schema::ArrowError> {
    let columns = schema
        .fields()
        .iter()
        .map(|field| match batch.column_by_name(field.name()) {
            Some(column) if column.data_type() == field.data_type() => Ok(Arc::clone(column)),
            Some(column) => arrow_cast::cast(column, field.data_type()),
            None => Ok(arrow_array::new_null_array(
                field.data_type(),
                batch.num_rows(),
            )),
        })
        .collect::<Result<Vec<_>, _>>()?;
    let options = arrow_array::RecordBatchOptions::new().with_row_count(Some(batch.num_rows()));
    arrow_array::RecordBatch::try_new_with_options(Arc::clone(schema), columns, &options)
}

/// DataFusion's "table ... not found", with the tables there are.
fn unknown_table_named(
    ctx: &SessionContext,
    error: &datafusion::error::DataFusionError,
) -> Option<Status> {
    let text = error.to_string();
    if !(text.contains("table '") && text.contains("not found")) {
        return None;
    }
    let mut names: Vec<String> = ctx
        .catalog(CATALOG)
        .and_then(|catalog| catalog.schema(SCHEMA))
        .map(|schema| schema.table_names())
        .unwrap_or_default();
    names.sort();
    Some(Status::invalid_argument(format!(
        "{}; the tables are: {} (and the table function latest_at)",
        text.replace('\n', " "),
        names.join(", ")
    )))
}

#[expect(clippy::needless_pass_by_value, reason = "the shape `map_err` takes")]
fn query_error(error: datafusion::error::DataFusionError) -> Status {
    Status::invalid_argument(error.to_string().replace('\n', " "))
}

fn sql_info() -> &'static SqlInfoData {
    static INFO: OnceLock<SqlInfoData> = OnceLock::new();
    INFO.get_or_init(|| {
        let mut builder = SqlInfoDataBuilder::new();
        builder.append(SqlInfo::FlightSqlServerName, "chunkstore");
        builder.append(SqlInfo::FlightSqlServerVersion, env!("CARGO_PKG_VERSION"));
        builder.append(SqlInfo::FlightSqlServerArrowVersion, "1.3");
        builder.append(SqlInfo::FlightSqlServerReadOnly, true);
        builder.append(SqlInfo::FlightSqlServerSql, true);
        builder.append(SqlInfo::FlightSqlServerSubstrait, false);
        builder.append(SqlInfo::FlightSqlServerTransaction, 0i32);
        builder.append(SqlInfo::FlightSqlServerCancel, false);
        // The builder only fails on a value type it does not know; these are all known.
        builder.build().unwrap_or_else(|_| {
            let mut fallback = SqlInfoDataBuilder::new();
            fallback.append(SqlInfo::FlightSqlServerName, "chunkstore");
            #[expect(clippy::expect_used, reason = "a string value always builds")]
            fallback.build().expect("a server name builds")
        })
    })
}

fn batch_stream(
    schema: arrow_schema::SchemaRef,
    batch: Result<arrow_array::RecordBatch, FlightError>,
) -> Response<DoGetStream> {
    let stream = FlightDataEncoderBuilder::new()
        .with_schema(schema)
        .build(futures::stream::once(async { batch }))
        .map_err(Status::from);
    Response::new(Box::pin(stream))
}

fn metadata_info(
    schema: &Schema,
    command: &impl arrow_flight::sql::ProstMessageExt,
    descriptor: FlightDescriptor,
) -> Result<Response<FlightInfo>, Status> {
    let endpoint = FlightEndpoint::new().with_ticket(Ticket {
        ticket: command.as_any().encode_to_vec().into(),
    });
    let info = FlightInfo::new()
        .try_with_schema(schema)
        .map_err(|e| Status::internal(format!("encoding the schema: {e}")))?
        .with_endpoint(endpoint)
        .with_descriptor(descriptor);
    Ok(Response::new(info))
}

#[tonic::async_trait]
impl FlightSqlService for SqlService {
    type FlightService = Self;

    async fn get_flight_info_statement(
        &self,
        query: CommandStatementQuery,
        request: Request<FlightDescriptor>,
    ) -> Result<Response<FlightInfo>, Status> {
        self.statement_info(&Statement::new(query.query), request.into_inner())
            .await
    }

    async fn get_flight_info_prepared_statement(
        &self,
        query: CommandPreparedStatementQuery,
        request: Request<FlightDescriptor>,
    ) -> Result<Response<FlightInfo>, Status> {
        let statement = Statement::decode(&query.prepared_statement_handle)?;
        self.statement_info(&statement, request.into_inner()).await
    }

    async fn do_get_statement(
        &self,
        ticket: TicketStatementQuery,
        _request: Request<Ticket>,
    ) -> Result<Response<DoGetStream>, Status> {
        let (statement, advertised) = StatementTicket::decode(&ticket.statement_handle)?;
        self.run(&statement, advertised).await
    }

    async fn do_get_prepared_statement(
        &self,
        query: CommandPreparedStatementQuery,
        _request: Request<Ticket>,
    ) -> Result<Response<DoGetStream>, Status> {
        let statement = Statement::decode(&query.prepared_statement_handle)?;
        self.run(&statement, None).await
    }

    async fn do_action_create_prepared_statement(
        &self,
        query: ActionCreatePreparedStatementRequest,
        _request: Request<arrow_flight::Action>,
    ) -> Result<ActionCreatePreparedStatementResult, Status> {
        let statement = Statement::new(query.query);
        let frame = self.plan(&statement).await?;
        let schema = frame.schema().as_arrow().clone();
        let parameters = parameter_schema(frame.logical_plan())?;
        Ok(ActionCreatePreparedStatementResult {
            prepared_statement_handle: statement.encode()?.into(),
            dataset_schema: schema_bytes(&schema)?,
            parameter_schema: if parameters.fields().is_empty() {
                bytes::Bytes::default()
            } else {
                schema_bytes(&parameters)?
            },
        })
    }

    /// Binds values to a prepared statement's parameters: the answer is a new handle
    /// that holds them (the server keeps nothing per statement).
    async fn do_put_prepared_statement_query(
        &self,
        query: CommandPreparedStatementQuery,
        request: Request<PeekableFlightDataStream>,
    ) -> Result<DoPutPreparedStatementResult, Status> {
        let statement = Statement::decode(&query.prepared_statement_handle)?;
        let flight_data = request
            .into_inner()
            .map_err(|status| FlightError::Tonic(Box::new(status)));
        let values: Vec<arrow_array::RecordBatch> =
            FlightRecordBatchStream::new_from_flight_data(flight_data)
                .try_collect()
                .await
                .map_err(|e| Status::invalid_argument(format!("reading the parameters: {e}")))?;
        let bound = Statement::new(statement.sql).bound(&values)?;
        Ok(DoPutPreparedStatementResult {
            prepared_statement_handle: Some(bound.encode()?.into()),
        })
    }

    async fn do_action_close_prepared_statement(
        &self,
        _query: ActionClosePreparedStatementRequest,
        _request: Request<arrow_flight::Action>,
    ) -> Result<(), Status> {
        // Nothing is kept per statement.
        Ok(())
    }

    async fn get_flight_info_sql_info(
        &self,
        query: CommandGetSqlInfo,
        request: Request<FlightDescriptor>,
    ) -> Result<Response<FlightInfo>, Status> {
        let schema = query.clone().into_builder(sql_info()).schema();
        metadata_info(&schema, &query, request.into_inner())
    }

    async fn do_get_sql_info(
        &self,
        query: CommandGetSqlInfo,
        _request: Request<Ticket>,
    ) -> Result<Response<DoGetStream>, Status> {
        let builder = query.into_builder(sql_info());
        Ok(batch_stream(builder.schema(), builder.build()))
    }

    async fn get_flight_info_catalogs(
        &self,
        query: CommandGetCatalogs,
        request: Request<FlightDescriptor>,
    ) -> Result<Response<FlightInfo>, Status> {
        let schema = query.into_builder().schema();
        metadata_info(&schema, &query, request.into_inner())
    }

    async fn do_get_catalogs(
        &self,
        query: CommandGetCatalogs,
        _request: Request<Ticket>,
    ) -> Result<Response<DoGetStream>, Status> {
        let mut builder = query.into_builder();
        builder.append(CATALOG);
        Ok(batch_stream(builder.schema(), builder.build()))
    }

    async fn get_flight_info_schemas(
        &self,
        query: CommandGetDbSchemas,
        request: Request<FlightDescriptor>,
    ) -> Result<Response<FlightInfo>, Status> {
        let schema = query.clone().into_builder().schema();
        metadata_info(&schema, &query, request.into_inner())
    }

    async fn do_get_schemas(
        &self,
        query: CommandGetDbSchemas,
        _request: Request<Ticket>,
    ) -> Result<Response<DoGetStream>, Status> {
        let mut builder = query.into_builder();
        builder.append(CATALOG, SCHEMA);
        Ok(batch_stream(builder.schema(), builder.build()))
    }

    async fn get_flight_info_tables(
        &self,
        query: CommandGetTables,
        request: Request<FlightDescriptor>,
    ) -> Result<Response<FlightInfo>, Status> {
        let schema = query.clone().into_builder().schema();
        metadata_info(&schema, &query, request.into_inner())
    }

    async fn do_get_tables(
        &self,
        query: CommandGetTables,
        _request: Request<Ticket>,
    ) -> Result<Response<DoGetStream>, Status> {
        let ctx = self.session()?;
        let include_schema = query.include_schema;
        let mut builder = query.into_builder();
        let names = ctx
            .catalog(CATALOG)
            .and_then(|c| c.schema(SCHEMA))
            .map(|s| s.table_names())
            .unwrap_or_default();
        let mut names = names;
        names.sort();
        for name in names {
            let schema = if include_schema {
                match ctx.table_provider(name.as_str()).await {
                    Ok(table) => table.schema().as_ref().clone(),
                    Err(_) => Schema::empty(),
                }
            } else {
                Schema::empty()
            };
            builder
                .append(CATALOG, SCHEMA, &name, "TABLE", &schema)
                .map_err(Status::from)?;
        }
        Ok(batch_stream(builder.schema(), builder.build()))
    }

    async fn get_flight_info_table_types(
        &self,
        query: CommandGetTableTypes,
        request: Request<FlightDescriptor>,
    ) -> Result<Response<FlightInfo>, Status> {
        let schema = query.into_builder().schema();
        metadata_info(&schema, &query, request.into_inner())
    }

    async fn do_get_table_types(
        &self,
        query: CommandGetTableTypes,
        _request: Request<Ticket>,
    ) -> Result<Response<DoGetStream>, Status> {
        // Every table here is one (GetTables says TABLE for each).
        let mut builder = query.into_builder();
        builder.append("TABLE");
        Ok(batch_stream(builder.schema(), builder.build()))
    }

    async fn register_sql_info(&self, _id: i32, _result: &SqlInfo) {}

    /// [`recordings::DROP_ACTION`]: drops a recording (behind the token, as every call).
    async fn do_action_fallback(
        &self,
        request: Request<arrow_flight::Action>,
    ) -> Result<
        Response<<Self as arrow_flight::flight_service_server::FlightService>::DoActionStream>,
        Status,
    > {
        let action = request.into_inner();
        if action.r#type != recordings::DROP_ACTION {
            return Err(Status::invalid_argument(format!(
                "unknown action {:?}: this server's own is {:?}",
                action.r#type,
                recordings::DROP_ACTION
            )));
        }
        let id = std::str::from_utf8(&action.body)
            .map_err(|_| Status::invalid_argument("a recording id is UTF-8 text"))?
            .to_owned();
        let state = Arc::clone(&self.state);
        let dropped = tokio::task::spawn_blocking(move || state.drop_recording(&id))
            .await
            .map_err(|e| Status::internal(format!("a server task failed: {e}")))??;
        let result = arrow_flight::Result {
            body: dropped.into(),
        };
        Ok(Response::new(Box::pin(futures::stream::once(async move {
            Ok(result)
        }))))
    }

    async fn list_custom_actions(&self) -> Option<Vec<Result<arrow_flight::ActionType, Status>>> {
        Some(vec![Ok(arrow_flight::ActionType {
            r#type: recordings::DROP_ACTION.to_owned(),
            description: "Drops a recording from memory and from the --persist log; the body \
                          is its recording id (rerun_segment_id)."
                .to_owned(),
        })])
    }
}
