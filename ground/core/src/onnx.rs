//! A trained actor as an ONNX model (the deterministic action, what the onboard blobs fly):
//! input `observation` `(batch, features)` float32, output `action` `(batch, 3)` float32, the
//! layers as `Gemm` (weights transposed, as stored) with `Relu` between them and `Tanh` at the
//! end. IR version 8, opset 17 (every runtime since 2022 reads it); the weights as raw
//! little-endian float32, bit for bit the actor's.
//!
//! Only the handful of ONNX messages the graph needs are declared, with their field numbers
//! from onnx.proto, and encoded by prost: no code generation, no protoc.

use prost::Message;
use shared::blob::Activation;
use shared::blob::ProblemKind;
use shared::quantize::MlpWeights;

/// ONNX IR version written (ONNX 1.10 and later read it).
pub const IR_VERSION: i64 = 8;
/// Opset of the default domain (Gemm, Relu and Tanh in their present forms).
pub const OPSET: i64 = 17;
/// The graph's input.
pub const INPUT: &str = "observation";
/// The graph's output.
pub const OUTPUT: &str = "action";

const FLOAT: i32 = 1;
const ATTRIBUTE_INT: i32 = 2;

#[derive(Clone, PartialEq, Message)]
struct ModelProto {
    #[prost(int64, tag = "1")]
    ir_version: i64,
    #[prost(string, tag = "2")]
    producer_name: String,
    #[prost(string, tag = "3")]
    producer_version: String,
    #[prost(string, tag = "6")]
    doc_string: String,
    #[prost(message, optional, tag = "7")]
    graph: Option<GraphProto>,
    #[prost(message, repeated, tag = "8")]
    opset_import: Vec<OperatorSetIdProto>,
    #[prost(message, repeated, tag = "14")]
    metadata_props: Vec<StringStringEntryProto>,
}

#[derive(Clone, PartialEq, Message)]
struct OperatorSetIdProto {
    #[prost(string, tag = "1")]
    domain: String,
    #[prost(int64, tag = "2")]
    version: i64,
}

#[derive(Clone, PartialEq, Message)]
struct StringStringEntryProto {
    #[prost(string, tag = "1")]
    key: String,
    #[prost(string, tag = "2")]
    value: String,
}

#[derive(Clone, PartialEq, Message)]
struct GraphProto {
    #[prost(message, repeated, tag = "1")]
    node: Vec<NodeProto>,
    #[prost(string, tag = "2")]
    name: String,
    #[prost(message, repeated, tag = "5")]
    initializer: Vec<TensorProto>,
    #[prost(message, repeated, tag = "11")]
    input: Vec<ValueInfoProto>,
    #[prost(message, repeated, tag = "12")]
    output: Vec<ValueInfoProto>,
}

#[derive(Clone, PartialEq, Message)]
struct NodeProto {
    #[prost(string, repeated, tag = "1")]
    input: Vec<String>,
    #[prost(string, repeated, tag = "2")]
    output: Vec<String>,
    #[prost(string, tag = "3")]
    name: String,
    #[prost(string, tag = "4")]
    op_type: String,
    #[prost(message, repeated, tag = "5")]
    attribute: Vec<AttributeProto>,
}

#[derive(Clone, PartialEq, Message)]
struct AttributeProto {
    #[prost(string, tag = "1")]
    name: String,
    #[prost(int64, tag = "3")]
    i: i64,
    #[prost(int32, tag = "20")]
    r#type: i32,
}

#[derive(Clone, PartialEq, Message)]
struct TensorProto {
    #[prost(int64, repeated, tag = "1")]
    dims: Vec<i64>,
    #[prost(int32, tag = "2")]
    data_type: i32,
    #[prost(string, tag = "8")]
    name: String,
    #[prost(bytes = "vec", tag = "9")]
    raw_data: Vec<u8>,
}

#[derive(Clone, PartialEq, Message)]
struct ValueInfoProto {
    #[prost(string, tag = "1")]
    name: String,
    #[prost(message, optional, tag = "2")]
    r#type: Option<TypeProto>,
}

#[derive(Clone, PartialEq, Message)]
struct TypeProto {
    #[prost(message, optional, tag = "1")]
    tensor_type: Option<TensorTypeProto>,
}

#[derive(Clone, PartialEq, Message)]
struct TensorTypeProto {
    #[prost(int32, tag = "1")]
    elem_type: i32,
    #[prost(message, optional, tag = "2")]
    shape: Option<TensorShapeProto>,
}

#[derive(Clone, PartialEq, Message)]
struct TensorShapeProto {
    #[prost(message, repeated, tag = "1")]
    dim: Vec<Dimension>,
}

#[derive(Clone, PartialEq, Message)]
struct Dimension {
    #[prost(int64, optional, tag = "1")]
    dim_value: Option<i64>,
    #[prost(string, optional, tag = "2")]
    dim_param: Option<String>,
}

/// Why a network cannot be written as ONNX.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum OnnxError {
    /// The layers do not chain (a layer's inputs are not the previous one's outputs), a layer's
    /// arrays have the wrong length, or there is no layer.
    #[error("the network's layers do not chain: {0}")]
    Shape(String),
}

fn float_input(name: &str, batch: &str, width: usize) -> ValueInfoProto {
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            tensor_type: Some(TensorTypeProto {
                elem_type: FLOAT,
                shape: Some(TensorShapeProto {
                    dim: vec![
                        Dimension {
                            dim_value: None,
                            dim_param: Some(batch.into()),
                        },
                        Dimension {
                            dim_value: Some(width as i64),
                            dim_param: None,
                        },
                    ],
                }),
            }),
        }),
    }
}

fn tensor(name: String, dims: Vec<i64>, values: &[f32]) -> TensorProto {
    TensorProto {
        dims,
        data_type: FLOAT,
        name,
        raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

fn node(op: &str, name: String, input: Vec<String>, output: String, attribute: Vec<AttributeProto>) -> NodeProto {
    NodeProto {
        input,
        output: vec![output],
        name,
        op_type: op.into(),
        attribute,
    }
}

/// The ONNX model of `network` (its layers in order, their activations as stored), with
/// `metadata` as the model's metadata properties (key, value).
pub fn actor_onnx(network: &MlpWeights, metadata: &[(&str, &str)]) -> Result<Vec<u8>, OnnxError> {
    let first = network
        .layers
        .first()
        .ok_or_else(|| OnnxError::Shape("no layer".into()))?;
    let mut nodes = Vec::new();
    let mut initializer = Vec::new();
    let mut current = INPUT.to_string();
    let mut width = first.inputs;
    let last = network.layers.len() - 1;
    for (i, layer) in network.layers.iter().enumerate() {
        if layer.inputs != width
            || layer.weights.len() != layer.inputs * layer.outputs
            || layer.bias.len() != layer.outputs
        {
            return Err(OnnxError::Shape(format!(
                "layer {i}: {} inputs after {width} outputs, {} weights, {} biases for {} outputs",
                layer.inputs,
                layer.weights.len(),
                layer.bias.len(),
                layer.outputs
            )));
        }
        let (w, b) = (format!("layer{i}.weight"), format!("layer{i}.bias"));
        initializer.push(tensor(
            w.clone(),
            vec![layer.outputs as i64, layer.inputs as i64],
            &layer.weights,
        ));
        initializer.push(tensor(b.clone(), vec![layer.outputs as i64], &layer.bias));
        let linear = format!("layer{i}.linear");
        let trans_b = AttributeProto {
            name: "transB".into(),
            i: 1,
            r#type: ATTRIBUTE_INT,
        };
        nodes.push(node(
            "Gemm",
            format!("layer{i}.gemm"),
            vec![current, w, b],
            linear.clone(),
            vec![trans_b],
        ));
        let out = if i == last {
            OUTPUT.to_string()
        } else {
            format!("layer{i}.out")
        };
        let op = match layer.activation {
            Activation::Relu => "Relu",
            Activation::Tanh => "Tanh",
        };
        nodes.push(node(
            op,
            format!("layer{i}.{}", op.to_lowercase()),
            vec![linear],
            out.clone(),
            Vec::new(),
        ));
        current = out;
        width = layer.outputs;
    }
    let problem = match network.features.problem() {
        ProblemKind::Transfer => "transfer",
        ProblemKind::Rendezvous => "rendezvous",
    };
    let model = ModelProto {
        ir_version: IR_VERSION,
        producer_name: "lowthrust".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        doc_string: format!(
            "The deterministic action of a {problem} actor: observation (the onboard features, float32) -> action (throttle and direction in [-1, 1])."
        ),
        graph: Some(GraphProto {
            node: nodes,
            name: format!("lowthrust-{problem}-actor"),
            initializer,
            input: vec![float_input(INPUT, "batch", first.inputs)],
            output: vec![float_input(OUTPUT, "batch", width)],
        }),
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: OPSET,
        }],
        metadata_props: std::iter::once(("problem", problem))
            .chain(metadata.iter().copied())
            .map(|(key, value)| StringStringEntryProto {
                key: key.into(),
                value: value.into(),
            })
            .collect(),
    };
    Ok(model.encode_to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::quantize::DenseWeights;

    fn layer(inputs: usize, outputs: usize, activation: Activation) -> DenseWeights {
        DenseWeights {
            inputs,
            outputs,
            weights: (0..inputs * outputs).map(|k| k as f32 * 0.5 - 1.0).collect(),
            bias: (0..outputs).map(|k| k as f32).collect(),
            activation,
        }
    }

    /// The encoding decodes back to the graph it describes: the layers' weights byte for byte,
    /// one Gemm and one activation per layer, the input and output named and sized.
    #[test]
    fn the_model_decodes_to_the_networks_layers() {
        let network = MlpWeights {
            features: shared::blob::FeatureLayout::TransferPolar10,
            layers: vec![
                layer(10, 4, Activation::Relu),
                layer(4, 4, Activation::Relu),
                layer(4, 3, Activation::Tanh),
            ],
        };
        let bytes = actor_onnx(&network, &[("source", "test")]).unwrap();
        let model = ModelProto::decode(bytes.as_slice()).unwrap();
        assert_eq!((model.ir_version, model.opset_import[0].version), (IR_VERSION, OPSET));
        let graph = model.graph.unwrap();
        let ops: Vec<&str> = graph.node.iter().map(|n| n.op_type.as_str()).collect();
        assert_eq!(ops, ["Gemm", "Relu", "Gemm", "Relu", "Gemm", "Tanh"]);
        assert_eq!(graph.node[5].output, [OUTPUT]);
        assert_eq!(graph.node[0].input[0], INPUT);
        assert_eq!(graph.initializer.len(), 6);
        for (k, layer) in network.layers.iter().enumerate() {
            let w = &graph.initializer[2 * k];
            assert_eq!(w.dims, [layer.outputs as i64, layer.inputs as i64]);
            let floats: Vec<f32> = w
                .raw_data
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect();
            assert_eq!(floats, layer.weights);
        }
        let dims = |v: &ValueInfoProto| v.r#type.clone().unwrap().tensor_type.unwrap().shape.unwrap().dim;
        assert_eq!(dims(&graph.input[0])[1].dim_value, Some(10));
        assert_eq!(dims(&graph.output[0])[1].dim_value, Some(3));
        assert_eq!(model.metadata_props.len(), 2);
    }

    #[test]
    fn layers_that_do_not_chain_are_refused() {
        let broken = MlpWeights {
            features: shared::blob::FeatureLayout::TransferPolar10,
            layers: vec![layer(10, 4, Activation::Relu), layer(5, 3, Activation::Tanh)],
        };
        assert!(matches!(actor_onnx(&broken, &[]), Err(OnnxError::Shape(_))));
        let empty = MlpWeights {
            features: shared::blob::FeatureLayout::TransferPolar10,
            layers: vec![],
        };
        assert!(actor_onnx(&empty, &[]).is_err());
    }
}
