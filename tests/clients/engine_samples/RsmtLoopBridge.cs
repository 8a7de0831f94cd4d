// Test-only: the Unity sample's state loop (RsmtOnnxStateLoop.cs) driving the exported graphs, each run answered over
// stdin/stdout by onnxruntime in the Python test (tests/clients/test_engine_samples.py); the messages of
// rsmt_loop_bridge.cpp, with integers and flags as int32 (type 3), as Unity's Inference Engine passes them.
using System;
using System.Collections.Generic;
using System.IO;
using System.Text;
using Rsmt.Link.InEngine;

static class RsmtLoopBridge
{
    static readonly BinaryReader In = new BinaryReader(Console.OpenStandardInput());
    static readonly BinaryWriter Out = new BinaryWriter(Console.OpenStandardOutput());

    static string ReadString() { return Encoding.UTF8.GetString(In.ReadBytes((int)In.ReadUInt32())); }

    static string[] ReadNames()
    {
        var names = new string[In.ReadUInt32()];
        for (int i = 0; i < names.Length; i++) names[i] = ReadString();
        return names;
    }

    static Dictionary<string, RsmtTensor> ReadSet()
    {
        var set = new Dictionary<string, RsmtTensor>();
        uint count = In.ReadUInt32();
        for (uint i = 0; i < count; i++)
        {
            string name = ReadString();
            byte type = In.ReadByte();
            var shape = new int[In.ReadUInt32()];
            for (int d = 0; d < shape.Length; d++) shape[d] = (int)In.ReadInt64();
            byte[] bytes = In.ReadBytes((int)In.ReadUInt64());
            if (type == 0)
            {
                var f = new float[bytes.Length / 4];
                Buffer.BlockCopy(bytes, 0, f, 0, bytes.Length);
                set[name] = new RsmtTensor(shape, f);
            }
            else if (type == 3)
            {
                var n = new int[bytes.Length / 4];
                Buffer.BlockCopy(bytes, 0, n, 0, bytes.Length);
                set[name] = new RsmtTensor(shape, n);
            }
            else throw new InvalidDataException("int32 and float32 tensors only, got type " + type);
        }
        return set;
    }

    static void WriteSet(Dictionary<string, RsmtTensor> set)
    {
        Out.Write((uint)set.Count);
        foreach (var kv in set)
        {
            byte[] name = Encoding.UTF8.GetBytes(kv.Key);
            Out.Write((uint)name.Length);
            Out.Write(name);
            Out.Write((byte)(kv.Value.IsInt ? 3 : 0));
            Out.Write((uint)kv.Value.Shape.Length);
            foreach (int d in kv.Value.Shape) Out.Write((long)d);
            int n = kv.Value.IsInt ? kv.Value.Ints.Length : kv.Value.Floats.Length;
            var bytes = new byte[4 * n];
            if (kv.Value.IsInt) Buffer.BlockCopy(kv.Value.Ints, 0, bytes, 0, bytes.Length);
            else Buffer.BlockCopy(kv.Value.Floats, 0, bytes, 0, bytes.Length);
            Out.Write((ulong)bytes.Length);
            Out.Write(bytes);
        }
    }

    sealed class PipeGraph : IRsmtGraph
    {
        readonly uint index;
        readonly string[] names;
        public PipeGraph(uint index, string[] names) { this.index = index; this.names = names; }
        public IList<string> InputNames { get { return names; } }
        public Dictionary<string, RsmtTensor> Run(Dictionary<string, RsmtTensor> inputs)
        {
            Out.Write((byte)1);
            Out.Write(index);
            WriteSet(inputs);
            Out.Flush();
            return ReadSet();
        }
        public void Dispose() { }
    }

    static int Main()
    {
        var graphs = new PipeGraph[4];
        for (uint g = 0; g < 4; g++) graphs[g] = new PipeGraph(g, ReadNames());
        string[] memory = ReadNames();
        var request = ReadSet();
        var style = new Dictionary<string, RsmtTensor>();
        foreach (var kv in request) if (kv.Key.StartsWith("style.", StringComparison.Ordinal)) style[kv.Key.Substring(6)] = kv.Value;
        var loop = new RsmtOnnxStateLoop(graphs[0], graphs[1], graphs[2], graphs[3], memory);
        int frames = request["frames"].Ints[0], retargetAt = request["retarget_at"].Ints[0];
        loop.Start(request["context_rotations"], request["context_roots"], request["target_rotations"],
                   request["target_roots"], style, frames, request["noise"].Floats);
        while (!loop.Done)
        {
            if (loop.Seq == retargetAt) loop.Retarget(request["retarget_rotations"], request["retarget_roots"], 0);
            float[] rotations, root;
            loop.Next(out rotations, out root);
            Out.Write((byte)2);
            WriteSet(new Dictionary<string, RsmtTensor> {
                { "rotations", new RsmtTensor(new[] { rotations.Length }, rotations) },
                { "root", new RsmtTensor(new[] { 3 }, root) } });
        }
        Out.Write((byte)3);
        Out.Flush();
        return 0;
    }
}
