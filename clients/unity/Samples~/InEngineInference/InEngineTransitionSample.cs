// Sample: the RSMT network inside Unity, no server. Assign the five ModelAssets exported by `rsmt export onnx`
// (prepare, style, begin, step, output), the sidecar's output_memory list and the character's RsmtJointMap-ordered
// Transforms; press Space to run a transition from the recorded context to the target, one frame per Update at the
// model's 30 fps. Poses are in the model's axes and centimetres: RsmtCoordinates converts them for Unity.
using System.Collections.Generic;
using Rsmt.Link.InEngine;
using Unity.InferenceEngine;
using UnityEngine;

public sealed class InEngineTransitionSample : MonoBehaviour
{
    public ModelAsset prepareGraph, styleGraph, beginGraph, stepGraph, outputGraph;
    public string[] outputMemory;      // the sidecar's "output_memory", in order
    public int noiseWidth = 384;       // 2 * the sidecar's sampler.width
    [Range(1, 120)] public int frames = 40;

    // Recorded by the game (model axes, cm): the last context frames, the target frame and a style clip.
    public float[] contextRotations;   // [K * J * 4]
    public float[] contextRoots;       // [K * 3]
    public float[] targetRotations;    // [J * 4]
    public float[] targetRoots;        // [3]
    public float[] styleRotations;     // [T * J * 4]
    public float[] styleRoots;         // [T * 3]
    public int joints = 21;

    RsmtInferenceEngineGraph prepare, style, begin, step, output;
    RsmtOnnxStateLoop loop;
    public float[] lastRotations, lastRoot;

    void OnEnable()
    {
        prepare = new RsmtInferenceEngineGraph(prepareGraph);
        style = new RsmtInferenceEngineGraph(styleGraph);
        begin = new RsmtInferenceEngineGraph(beginGraph);
        step = new RsmtInferenceEngineGraph(stepGraph);
        output = new RsmtInferenceEngineGraph(outputGraph);
        loop = new RsmtOnnxStateLoop(prepare, begin, step, output, outputMemory);
    }

    void Update()
    {
        if (Input.GetKeyDown(KeyCode.Space))
        {
            int t = styleRoots.Length / 3, k = contextRoots.Length / 3;
            var styleContext = style.Run(new Dictionary<string, RsmtTensor> {
                { "rotations", new RsmtTensor(new[] { 1, t, joints, 4 }, styleRotations) },
                { "roots", new RsmtTensor(new[] { 1, t, 3 }, styleRoots) } });
            loop.Start(new RsmtTensor(new[] { k, joints, 4 }, contextRotations), new RsmtTensor(new[] { k, 3 }, contextRoots),
                       new RsmtTensor(new[] { 1, joints, 4 }, targetRotations), new RsmtTensor(new[] { 1, 3 }, targetRoots),
                       styleContext, frames, new float[noiseWidth]);
        }
        if (loop != null && loop.FramesTotal > 0 && !loop.Done) loop.Next(out lastRotations, out lastRoot);
    }

    void OnDisable()
    {
        foreach (var g in new[] { prepare, style, begin, step, output }) if (g != null) g.Dispose();
    }
}
