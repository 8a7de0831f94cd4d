// IRsmtGraph on Unity's Inference Engine (package com.unity.ai.inference 2.2+; Sentis 2.1 has the same API under
// the namespace Unity.Sentis): one exported RSMT graph (a ModelAsset imported from its .onnx file) run by a Worker.
using System.Collections.Generic;
using Unity.InferenceEngine;

namespace Rsmt.Link.InEngine
{
    public sealed class RsmtInferenceEngineGraph : IRsmtGraph
    {
        readonly Model model;
        readonly Worker worker;
        readonly List<string> inputNames = new List<string>();
        readonly List<string> outputNames = new List<string>();

        public RsmtInferenceEngineGraph(ModelAsset asset, BackendType backend = BackendType.CPU)
        {
            model = ModelLoader.Load(asset);
            foreach (var input in model.inputs) inputNames.Add(input.name);
            foreach (var output in model.outputs) outputNames.Add(output.name);
            worker = new Worker(model, backend);
        }

        public IList<string> InputNames { get { return inputNames; } }

        public Dictionary<string, RsmtTensor> Run(Dictionary<string, RsmtTensor> inputs)
        {
            var owned = new List<Tensor>();
            foreach (var kv in inputs)
            {
                var shape = new TensorShape(kv.Value.Shape);
                Tensor tensor = kv.Value.IsInt ? (Tensor)new Tensor<int>(shape, kv.Value.Ints)
                                               : new Tensor<float>(shape, kv.Value.Floats);
                worker.SetInput(kv.Key, tensor);
                owned.Add(tensor);
            }
            worker.Schedule();
            var result = new Dictionary<string, RsmtTensor>();
            foreach (string name in outputNames)
            {
                var peeked = worker.PeekOutput(name);
                int[] dims = peeked.shape.ToArray();
                var floats = peeked as Tensor<float>;
                result[name] = floats != null ? new RsmtTensor(dims, floats.DownloadToArray())
                                              : new RsmtTensor(dims, ((Tensor<int>)peeked).DownloadToArray());
            }
            foreach (var t in owned) t.Dispose();
            return result;
        }

        public void Dispose() { worker.Dispose(); }
    }
}
