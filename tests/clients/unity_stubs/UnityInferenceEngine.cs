// STUB OF UNITY'S INFERENCE ENGINE API (package com.unity.ai.inference), test-only: the few types and members the
// in-engine sample (clients/unity/Samples~/InEngineInference) calls, with Unity's signatures, so that mcs can
// type-check the sample without Unity. Nothing here runs a network: bodies throw or return empty values.
using System;
using System.Collections.Generic;

namespace Unity.InferenceEngine
{
    public enum BackendType { GPUCompute, CPU }

    public class ModelAsset : UnityEngine.ScriptableObject { }

    public class Model
    {
        public struct Input { public string name; }
        public struct Output { public string name; }
        public List<Input> inputs = new List<Input>();
        public List<Output> outputs = new List<Output>();
    }

    public static class ModelLoader
    {
        public static Model Load(ModelAsset asset) { throw new NotSupportedException("stub of the Inference Engine API"); }
    }

    public struct TensorShape
    {
        readonly int[] dims;
        public TensorShape(params int[] shape) { dims = shape; }
        public int[] ToArray() { return dims; }
    }

    public abstract class Tensor : IDisposable
    {
        public TensorShape shape;
        public void Dispose() { }
    }

    public class Tensor<T> : Tensor where T : struct
    {
        public Tensor(TensorShape shape, T[] srcData) { this.shape = shape; }
        public T[] DownloadToArray() { return new T[0]; }
    }

    public class Worker : IDisposable
    {
        public Worker(Model model, BackendType backendType) { }
        public void SetInput(string name, Tensor input) { }
        public void Schedule() { }
        public Tensor PeekOutput(string name) { throw new NotSupportedException("stub of the Inference Engine API"); }
        public void Dispose() { }
    }
}
