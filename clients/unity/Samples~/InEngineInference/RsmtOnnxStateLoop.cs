// The state loop of the exported RSMT graphs (rsmt export onnx), independent of any inference runtime: which graph
// runs when, which outputs feed which inputs, and what each character keeps between frames. The runtime behind
// IRsmtGraph runs one graph (RsmtInferenceEngineGraph.cs: Unity's Inference Engine). Names and shapes are the
// sidecar's (rsmt-onnx.json); integer and boolean tensors travel as int (the Inference Engine imports int64 and bool
// as int32).
using System;
using System.Collections.Generic;

namespace Rsmt.Link.InEngine
{
    /// A tensor by shape and values: floats, or ints for the graphs' int64 and bool tensors.
    public sealed class RsmtTensor
    {
        public readonly int[] Shape;
        public readonly float[] Floats;
        public readonly int[] Ints;

        public RsmtTensor(int[] shape, float[] floats) { Shape = shape; Floats = floats; }
        public RsmtTensor(int[] shape, int[] ints) { Shape = shape; Ints = ints; }
        public bool IsInt { get { return Ints != null; } }

        public static int Count(int[] shape)
        {
            int n = 1;
            foreach (int d in shape) n *= d;
            return n;
        }
    }

    /// One loaded graph: its input names (some exported inputs are dropped when a graph never reads them) and a run.
    public interface IRsmtGraph : IDisposable
    {
        IList<string> InputNames { get; }
        Dictionary<string, RsmtTensor> Run(Dictionary<string, RsmtTensor> inputs);
    }

    /// One character's transition run in-engine: prepare and begin once, then step and output every frame.
    public sealed class RsmtOnnxStateLoop
    {
        // The sampler state the step graph reads and returns (outputs are named NAME_out).
        static readonly string[] Stepped = { "h", "c", "rel", "vel", "rot", "root_xz", "phase", "tta" };
        static readonly string[] Held = { "target_pos", "target_rot", "target_emb", "noise" };
        static readonly string[] Pose = { "rel", "vel", "rot", "root_xz" };

        readonly IRsmtGraph prepare, begin, step, output;
        readonly string[] memoryKeys;
        readonly Dictionary<string, RsmtTensor> state = new Dictionary<string, RsmtTensor>();
        readonly Dictionary<string, RsmtTensor> memory = new Dictionary<string, RsmtTensor>();
        Dictionary<string, RsmtTensor> style;
        RsmtTensor yaw, origin;
        RsmtTensor[] context;
        float[] noise;
        bool late;

        public int FramesTotal { get; private set; }
        public int Seq { get; private set; }
        public bool Done { get { return Seq >= FramesTotal; } }

        /// ``memoryKeys``: the sidecar's "output_memory", in order.
        public RsmtOnnxStateLoop(IRsmtGraph prepare, IRsmtGraph begin, IRsmtGraph step, IRsmtGraph output,
                                 string[] memoryKeys)
        {
            this.prepare = prepare; this.begin = begin; this.step = step; this.output = output;
            this.memoryKeys = memoryKeys;
        }

        /// Start a transition of ``frames`` frames. ``contextRotations`` [K, J, 4] local x, y, z, w and
        /// ``contextRoots`` [K, 3] are the character's last K (the sidecar's sampler.context) frames on the model's rig
        /// (model axes, cm), ``targetRotations`` [1, J, 4] and ``targetRoots`` [1, 3] the pose to arrive at;
        /// ``styleContext`` the style graph's outputs for the style clip; ``noise`` [1, 2 * width] (zeros:
        /// deterministic).
        public void Start(RsmtTensor contextRotations, RsmtTensor contextRoots, RsmtTensor targetRotations,
                          RsmtTensor targetRoots, Dictionary<string, RsmtTensor> styleContext, int frames, float[] noise)
        {
            context = new[] { contextRotations, contextRoots };
            style = styleContext;
            this.noise = noise;
            var prepared = Prepare(targetRotations, targetRoots);
            yaw = prepared["yaw"];
            origin = prepared["origin"];
            memory.Clear();
            foreach (string key in memoryKeys) memory[key] = prepared[key];
            state.Clear();
            foreach (var kv in Begin(prepared, frames)) state[kv.Key.Substring(0, kv.Key.Length - "_out".Length)] = kv.Value;
            FramesTotal = frames;
            Seq = 0;
            late = false;
        }

        /// A new target mid-stream, from the next frame; ``frames``: the frames left from then (0: unchanged). The
        /// transition keeps its canonical frame (prepare gives the same one for the same context) and its recurrent
        /// state: only the target's part of the state is replaced (begin encodes it).
        public void Retarget(RsmtTensor targetRotations, RsmtTensor targetRoots, int frames)
        {
            var began = Begin(Prepare(targetRotations, targetRoots), Math.Max(1, FramesTotal - Seq));
            foreach (string key in new[] { "target_pos", "target_rot", "target_emb" }) state[key] = began[key + "_out"];
            if (frames > 0)
            {
                state["tta"] = new RsmtTensor(new[] { 1 }, new[] { frames });
                FramesTotal = Seq + frames;
            }
            late = true;  // the retarget facing window of the step's steering
        }

        Dictionary<string, RsmtTensor> Prepare(RsmtTensor targetRotations, RsmtTensor targetRoots)
        {
            return prepare.Run(new Dictionary<string, RsmtTensor> {
                { "context_rotations", context[0] }, { "context_roots", context[1] },
                { "target_rotations", targetRotations }, { "target_roots", targetRoots } });
        }

        Dictionary<string, RsmtTensor> Begin(Dictionary<string, RsmtTensor> prepared, int frames)
        {
            var inputs = new Dictionary<string, RsmtTensor>(style);
            foreach (var kv in prepared)
                if (kv.Key.StartsWith("context_", StringComparison.Ordinal) || kv.Key.StartsWith("target_", StringComparison.Ordinal))
                    inputs[kv.Key] = kv.Value;
            inputs["frames"] = new RsmtTensor(new[] { 1 }, new[] { frames });
            inputs["noise"] = new RsmtTensor(new[] { 1, noise.Length }, noise);
            inputs["velocity_known"] = new RsmtTensor(new[] { 1 }, new[] { 0 });  // the target frame alone
            return begin.Run(Only(begin, inputs));
        }

        /// One frame: ``rotations`` [J * 4] local x, y, z, w and ``root`` [3], world space, model axes (cm).
        public void Next(out float[] rotations, out float[] root)
        {
            if (Done) throw new InvalidOperationException("the transition has ended");
            var inputs = new Dictionary<string, RsmtTensor>(style);
            foreach (string key in Stepped) inputs[key] = state[key];
            foreach (string key in Held) inputs[key] = state[key];
            inputs["late"] = new RsmtTensor(new[] { 1 }, new[] { late ? 1 : 0 });
            var stepped = step.Run(Only(step, inputs));
            foreach (string key in Stepped) state[key] = stepped[key + "_out"];
            var outInputs = new Dictionary<string, RsmtTensor>(memory);
            foreach (string key in Pose) outInputs[key] = state[key];
            outInputs["yaw"] = yaw;
            outInputs["origin"] = origin;
            outInputs["remaining"] = new RsmtTensor(new[] { 1 }, new[] { FramesTotal - Seq - 1 });
            outInputs["shift"] = stepped["shift"];
            var frame = output.Run(Only(output, outInputs));
            foreach (string key in memoryKeys) memory[key] = frame[key + "_out"];
            rotations = frame["rotations"].Floats;
            root = frame["root_position"].Floats;
            Seq++;
        }

        static Dictionary<string, RsmtTensor> Only(IRsmtGraph graph, Dictionary<string, RsmtTensor> values)
        {
            var feed = new Dictionary<string, RsmtTensor>();
            foreach (string name in graph.InputNames)
            {
                RsmtTensor t;
                if (!values.TryGetValue(name, out t)) throw new ArgumentException("no value for the graph input " + name);
                feed[name] = t;
            }
            return feed;
        }
    }
}
