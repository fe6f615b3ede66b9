//! The ROS 2 parameter services of a node, served by us rather than by ros2-client, so that
//! they say what the node really does (ADR 0025):
//!
//! * `describe_parameters` gives each parameter's description, its range or allowed values
//!   (and the rules across parameters, in `additional_constraints`) and whether it is
//!   read-only, from the node's [`Spec`]s;
//! * a set (`set_parameters`, `set_parameters_atomically`) is checked against the spec's
//!   type, read-only flag and rule, then handed to the node itself, on the node's own thread,
//!   between two turns; only when the node applied it is the value stored, reported
//!   successful and announced on `/parameter_events`. A refusal names the parameter and the
//!   rule. So `get_parameters` always returns what the node runs with, and no refused set
//!   leaves a value behind that would make later sets fail;
//! * `use_sim_time` is every node's: the node's clock then follows `/clock`, or, for a node
//!   that publishes `/clock` itself, a set to true is refused with the reason.
//!
//! The services are polled by the node's loop ([`ParameterServer::serve`]); with the loop's
//! naps of at most 20 ms that is the latency of a call.

use ros2_client::parameters::raw;
use ros2_client::rcl_interfaces::*;
use ros2_client::service::ServiceMapping;
use ros2_client::{Name, Node, ParameterValue, Publisher, QosProfile, Server, ServiceTypeName};
use serde_json::{Map, Value};

use oilfilm_graph::params::{Rule, Spec, USE_SIM_TIME};
use oilfilm_graph::stamp::Stamp;
use oilfilm_graph::NodeError;

use crate::dds::{from_parameter, mw, to_parameter, Paced};

/// A change the node is asked to apply: the whole parameter set as it would be after it.
pub struct Change<'a> {
    /// Every parameter of the node but `use_sim_time`.
    pub params: &'a Map<String, Value>,
    pub use_sim_time: bool,
    /// The names that change.
    pub changed: &'a [String],
}

/// Whether a node can follow `/clock`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SimTime {
    /// It follows `/clock` when `use_sim_time` is true.
    Follows,
    /// It publishes `/clock` itself (or its time is its data's): `use_sim_time` true is
    /// refused with this reason.
    Refused(&'static str),
}

struct Servers {
    get: Paced<Server<GetParametersRequest, GetParametersResponse>>,
    types: Paced<Server<GetParameterTypesRequest, GetParameterTypesResponse>>,
    set: Paced<Server<SetParametersRequest, SetParametersResponse>>,
    atomic: Paced<Server<SetParametersRequest, SetParametersAtomicallyResponse>>,
    list: Paced<Server<ListParametersRequest, ListParametersResponse>>,
    describe: Paced<Server<DescribeParametersRequest, DescribeParametersResponse>>,
}

/// One node's parameter services and its `/parameter_events` writer.
pub struct ParameterServer {
    servers: Servers,
    events: Paced<Publisher<raw::ParameterEvent>>,
    node_name: String,
    specs: Vec<Spec>,
    values: Map<String, Value>,
    use_sim_time: bool,
    sim_time: SimTime,
}

/// The QoS of the six services: reliable, volatile, keep-last 10 (rclcpp's services').
fn service_qos() -> QosProfile {
    crate::dds::qos_from(oilfilm_graph::topics::TopicQos { reliable: true, depth: 10, transient_local: false })
}

/// `/parameter_events` as our nodes offer it: reliable, keep-last 1000 and transient-local,
/// so a recorder that joins after a node started still gets the event that declared its
/// parameters (rclcpp's is volatile; a volatile reader matches either way).
pub fn parameter_events_qos() -> QosProfile {
    crate::dds::qos_from(oilfilm_graph::topics::TopicQos { reliable: true, depth: 1000, transient_local: true })
}

fn server<Req, Resp>(node: &mut Node, fqn: &str, service: &str, ty: &str) -> Result<Server<Req, Resp>, NodeError>
where
    Req: ros2_client::Message + Clone + 'static,
    Resp: ros2_client::Message + 'static,
{
    let name = Name::new(fqn, service).map_err(|e| mw(format!("service name {fqn}/{service}"), format!("{e:?}")))?;
    node.create_server(ServiceMapping::Enhanced, &name, &ServiceTypeName::new("rcl_interfaces", ty), service_qos(), service_qos())
        .map_err(|e| mw(format!("service {fqn}/{service}"), e))
}

/// The descriptor `ros2 param describe` shows.
fn descriptor(spec: &Spec, value: &Value) -> raw::ParameterDescriptor {
    let (integer_range, floating_point_range) = match spec.rule {
        Rule::Integer { min, max } => (vec![raw::IntegerRange { from_value: min, to_value: max, step: 0 }], vec![]),
        Rule::Number { min, max, .. } => (vec![], vec![raw::FloatingPointRange { from_value: min, to_value: max, step: 0.0 }]),
        _ => (vec![], vec![]),
    };
    raw::ParameterDescriptor {
        name: spec.name.to_string(),
        r#type: to_parameter(value).to_parameter_type() as u8,
        description: spec.description.to_string(),
        additional_constraints: spec.additional_constraints(),
        read_only: spec.read_only,
        dynamic_typing: false,
        floating_point_range,
        integer_range,
    }
}

/// A set as it would leave the node: its parameters, `use_sim_time`, and the names it changes.
type Prepared = (Map<String, Value>, bool, Vec<String>);

impl ParameterServer {
    /// The services of `node` (`fqn`: its fully qualified name) for parameters `specs` with
    /// their values `values`, and `use_sim_time`; announces the declared parameters on
    /// `/parameter_events`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        node: &mut Node,
        context: &ros2_client::Context,
        fqn: &str,
        specs: Vec<Spec>,
        values: Map<String, Value>,
        use_sim_time: bool,
        sim_time: SimTime,
        now: Stamp,
    ) -> Result<Self, NodeError> {
        let servers = Servers {
            get: Paced::new(server(node, fqn, "get_parameters", "GetParameters")?),
            types: Paced::new(server(node, fqn, "get_parameter_types", "GetParameterTypes")?),
            set: Paced::new(server(node, fqn, "set_parameters", "SetParameters")?),
            atomic: Paced::new(server(node, fqn, "set_parameters_atomically", "SetParametersAtomically")?),
            list: Paced::new(server(node, fqn, "list_parameters", "ListParameters")?),
            describe: Paced::new(server(node, fqn, "describe_parameters", "DescribeParameters")?),
        };
        let topic = context.get_parameter_events_topic();
        let events = node.create_publisher(&topic, Some(parameter_events_qos())).map_err(|e| mw("/parameter_events publisher", e))?;
        let s = Self { servers, events: Paced::new(events), node_name: fqn.to_string(), specs, values, use_sim_time, sim_time };
        let declared: Vec<String> = s.names();
        s.announce(now, &declared, true);
        Ok(s)
    }

    /// Whether the node's clock follows `/clock`.
    pub fn use_sim_time(&self) -> bool {
        self.use_sim_time
    }

    /// Every parameter's name, `use_sim_time` last.
    fn names(&self) -> Vec<String> {
        let mut n: Vec<String> = self.specs.iter().map(|s| s.name.to_string()).collect();
        n.push(USE_SIM_TIME.into());
        n
    }

    fn value(&self, name: &str) -> Option<Value> {
        if name == USE_SIM_TIME {
            return Some(Value::Bool(self.use_sim_time));
        }
        self.values.get(name).cloned()
    }

    fn use_sim_time_spec(&self) -> Spec {
        let mut s = Spec::live(
            USE_SIM_TIME,
            "take the node's time from /clock (rosgraph_msgs/msg/Clock) instead of the wall clock: the stamps of its log lines and parameter events, a recorder's log times",
            Rule::Any,
        );
        if let SimTime::Refused(why) = self.sim_time {
            s = s.with_constraints(why);
        }
        s
    }

    fn announce(&self, now: Stamp, names: &[String], new: bool) {
        let params: Vec<raw::Parameter> =
            names.iter().filter_map(|n| self.value(n).map(|v| raw::Parameter { name: n.clone(), value: to_parameter(&v).into() })).collect();
        let (new_parameters, changed_parameters) = if new { (params, Vec::new()) } else { (Vec::new(), params) };
        let event = raw::ParameterEvent {
            stamp: ros2_client::builtin_interfaces::Time::from_nanos(now.0),
            node: self.node_name.clone(),
            new_parameters,
            changed_parameters,
            deleted_parameters: Vec::new(),
        };
        if let Err(e) = self.events.publish(event) {
            tracing::warn!("/parameter_events: not published: {e:?}");
        }
    }

    /// Checks a set of `(name, value)` against the specs: the names known, the types kept,
    /// read-only ones unchanged. Returns the values as they would be and what changes.
    fn prepare(&self, set: &[raw::Parameter]) -> Result<Prepared, String> {
        let mut next = self.values.clone();
        let mut sim = self.use_sim_time;
        let mut changed = Vec::new();
        for p in set {
            let name = p.name.as_str();
            let value = ParameterValue::from(p.value.clone());
            if matches!(value, ParameterValue::NotSet) {
                return Err(format!("parameter `{name}`: cannot be undeclared (its parameters are fixed by the node)"));
            }
            if name == USE_SIM_TIME {
                let ParameterValue::Boolean(b) = value else {
                    return Err(format!("parameter `{USE_SIM_TIME}`: must be of type bool"));
                };
                if let (true, SimTime::Refused(why)) = (b, self.sim_time) {
                    return Err(format!("parameter `{USE_SIM_TIME}`: cannot be true: {why}"));
                }
                if b != sim {
                    changed.push(name.to_string());
                }
                sim = b;
                continue;
            }
            let Some(spec) = self.specs.iter().find(|s| s.name == name) else {
                return Err(format!("parameter `{name}`: not a parameter of {} (its parameters: {})", self.node_name, self.names().join(", ")));
            };
            let mut v = from_parameter(&value);
            // A whole number for a double parameter (`ros2 param set ... amplitude_n 350`).
            if let (Some(Value::Number(old)), Value::Number(n)) = (self.values.get(name), &v) {
                if !old.is_i64() && !old.is_u64() && (n.is_i64() || n.is_u64()) {
                    v = n.as_f64().and_then(serde_json::Number::from_f64).map_or(v.clone(), Value::Number);
                }
            }
            if self.values.get(name) == Some(&v) {
                continue;
            }
            if spec.read_only {
                return Err(format!(
                    "parameter `{name}` is read-only: it is fixed when {} starts; restart the node with `-p {name}:=...` (or in its params file)",
                    self.node_name
                ));
            }
            next.insert(name.to_string(), v);
            if !changed.iter().any(|c| c == name) {
                changed.push(name.to_string());
            }
        }
        Ok((next, sim, changed))
    }

    /// Applies a prepared set through the node (`apply`), and stores and announces it if the
    /// node took it.
    fn commit(&mut self, set: &[raw::Parameter], now: Stamp, apply: &mut dyn FnMut(&Change) -> Result<(), String>) -> Result<(), String> {
        let (next, sim, changed) = self.prepare(set)?;
        if changed.is_empty() {
            return Ok(());
        }
        apply(&Change { params: &next, use_sim_time: sim, changed: &changed })?;
        self.values = next;
        self.use_sim_time = sim;
        self.announce(now, &changed, false);
        Ok(())
    }

    /// Answers every request waiting; a set goes through `apply` (the node, between its
    /// turns). Returns how many requests were answered.
    pub fn serve(&mut self, now: Stamp, apply: &mut dyn FnMut(&Change) -> Result<(), String>) -> usize {
        let mut answered = 0;
        let warn = |what: &str, e: &dyn std::fmt::Debug| tracing::warn!("parameter service {what}: {e:?}");
        while let Ok(Some((id, req))) = self.servers.get.receive_request() {
            let values = req.names.iter().map(|n| self.value(n).map_or(ParameterValue::NotSet, |v| to_parameter(&v)).into()).collect();
            if let Err(e) = self.servers.get.send_response(id, GetParametersResponse { values }) {
                warn("get_parameters", &e);
            }
            answered += 1;
        }
        while let Ok(Some((id, req))) = self.servers.types.receive_request() {
            let values = req.names.iter().map(|n| self.value(n).map_or(0, |v| to_parameter(&v).to_parameter_type() as u8)).collect();
            if let Err(e) = self.servers.types.send_response(id, GetParameterTypesResponse { values }) {
                warn("get_parameter_types", &e);
            }
            answered += 1;
        }
        while let Ok(Some((id, req))) = self.servers.list.receive_request() {
            // Our names have no `.` namespaces: a prefix matches a name itself only.
            let names: Vec<String> = self.names().into_iter().filter(|n| req.prefixes.is_empty() || req.prefixes.iter().any(|p| p == n)).collect();
            let result = ListParametersResult { names, prefixes: Vec::new() };
            if let Err(e) = self.servers.list.send_response(id, ListParametersResponse { result }) {
                warn("list_parameters", &e);
            }
            answered += 1;
        }
        while let Ok(Some((id, req))) = self.servers.describe.receive_request() {
            let sim = self.use_sim_time_spec();
            let values = req
                .names
                .iter()
                .map(|n| {
                    let spec = if n == USE_SIM_TIME { Some(&sim) } else { self.specs.iter().find(|s| s.name == n) };
                    match (spec, self.value(n)) {
                        (Some(spec), Some(v)) => descriptor(spec, &v),
                        _ => raw::ParameterDescriptor {
                            name: n.clone(),
                            r#type: 0,
                            description: format!("not a parameter of {}", self.node_name),
                            additional_constraints: String::new(),
                            read_only: true,
                            dynamic_typing: false,
                            floating_point_range: vec![],
                            integer_range: vec![],
                        },
                    }
                })
                .collect();
            if let Err(e) = self.servers.describe.send_response(id, DescribeParametersResponse { values }) {
                warn("describe_parameters", &e);
            }
            answered += 1;
        }
        while let Ok(Some((id, req))) = self.servers.set.receive_request() {
            // One result per parameter, each applied on its own, in order (rclcpp's).
            let results = req
                .parameter
                .iter()
                .map(|p| {
                    let r = self.commit(std::slice::from_ref(p), now, apply);
                    log_set(&self.node_name, std::slice::from_ref(p), &r);
                    r.into()
                })
                .collect();
            if let Err(e) = self.servers.set.send_response(id, SetParametersResponse { results }) {
                warn("set_parameters", &e);
            }
            answered += 1;
        }
        while let Ok(Some((id, req))) = self.servers.atomic.receive_request() {
            let r = self.commit(&req.parameter, now, apply);
            log_set(&self.node_name, &req.parameter, &r);
            if let Err(e) = self.servers.atomic.send_response(id, SetParametersAtomicallyResponse { result: r.into() }) {
                warn("set_parameters_atomically", &e);
            }
            answered += 1;
        }
        answered
    }
}

/// A set's outcome in the node's log (and so on `/rosout`).
fn log_set(node: &str, set: &[raw::Parameter], r: &Result<(), String>) {
    let shown = |v: Value| if v.is_null() { "NaN".to_string() } else { v.to_string() };
    let names: Vec<String> = set.iter().map(|p| format!("{}={}", p.name, shown(from_parameter(&ParameterValue::from(p.value.clone()))))).collect();
    match r {
        Ok(()) => tracing::info!(node, "parameters set: {}", names.join(", ")),
        Err(e) => tracing::warn!(node, "parameters not set ({}): {e}", names.join(", ")),
    }
}
