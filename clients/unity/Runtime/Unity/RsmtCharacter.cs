// Drives one character's Transforms from an RSMT server. Messages are handled in Update and poses applied
// in LateUpdate (after the Animator, so they win), both on the main thread; nothing touches Unity objects
// from the socket thread.
using System.Collections.Generic;
using UnityEngine;

namespace Rsmt.Link.Unity
{
    public sealed class RsmtCharacter : MonoBehaviour
    {
        [Header("Server")]
        public string serverUrl = "http://127.0.0.1:8000";
        public string apiKey = "";
        public bool binaryFrames = true;
        [Tooltip("When the connection is lost (a replica died or drained), connect again and resume the transition from the frames received last")]
        public bool failover = false;

        [Header("Character")]
        public string characterId = "hero";
        public RsmtJointMap jointMap;
        [Tooltip("Top of the bone hierarchy (the Transforms named in the joint map are searched under it)")]
        public Transform skeletonRoot;
        [Tooltip("Seconds frames wait before they play: hides network and generation jitter")]
        public float bufferDelay = 0.1f;
        [Tooltip("Keep streaming while the window is unfocused (sets Application.runInBackground)")]
        public bool runInBackground = true;

        [Tooltip("Optional: bound from hello when it has no referencePose; StartTransitionFromRecorder reads its context")]
        public RsmtPoseRecorder recorder;

        [Header("Style")]
        [Tooltip("A BVH style clip registered at start (its id goes to styleId)")]
        public TextAsset styleClip;
        public string styleId;
        [Tooltip("How far a start moves the style from the model's neutral style (0 to 4; 1: as encoded); below 0: not sent, the server's setting")]
        public float styleStrength = -1f;

        RsmtStreamClient client;
        Transform[] bones;
        readonly Queue<System.Func<string>> pending = new Queue<System.Func<string>>();  // built when hello has come

        public bool Ready { get { return client != null && client.Hello != null && bones != null; } }

        /// <summary>True while a transition's frames are being applied (false before the first and after the last).</summary>
        public bool Playing { get; private set; }

        async void Start()
        {
            if (runInBackground) Application.runInBackground = true;
            client = new RsmtStreamClient(new ClientWebSocketTransport(), bufferDelay) { Failover = failover };
            client.HelloReceived += OnHello;
            client.ErrorReceived += m => Debug.LogWarning("RSMT " + m.Code + ": " + m.Text, this);
            client.Closed += (code, reason) => Debug.LogWarning("RSMT stream closed " + code + " " + reason, this);
            try
            {
                if (styleClip != null && string.IsNullOrEmpty(styleId))
                {
                    using (var http = new RsmtHttpClient(serverUrl, apiKey))
                    {
                        http.Cutter = new RsmtMotionCutter(RsmtMotionLimits.FromModel(await http.ModelAsync()));
                        http.Cutter.Notice += note => Debug.LogWarning("RSMT: " + note, this);  // a whole take as style clip
                        styleId = (await http.RegisterStyleAsync(styleClip.text, styleClip.name)).StyleId;
                    }
                    client.RememberStyle(styleId, styleClip.text, styleClip.name);  // registered again after a failover if needed
                }
                await client.ConnectAsync(serverUrl, apiKey, binaryFrames);
            }
            catch (System.Exception e)
            {
                Debug.LogError("RSMT: cannot connect to " + serverUrl + ": " + e.Message, this);
            }
        }

        void OnHello(RsmtHello hello)
        {
            var missing = new List<string>();
            bones = jointMap != null
                ? jointMap.Resolve(skeletonRoot, hello.Model.JointNames, missing)
                : RsmtJointBinding.Resolve(hello.Model.JointNames, null, true, n => FindBone(n), missing);
            if (missing.Count > 0) Debug.LogWarning("RSMT: no Transform for joint(s) " + string.Join(", ", missing.ToArray()), this);
            if (recorder != null && !recorder.Bound)
            {
                var parents = new int[hello.Model.Joints.Length];
                for (int j = 0; j < parents.Length; j++) parents[j] = hello.Model.Joints[j].Parent;
                recorder.Bind(hello.Model.JointNames, parents, client.MetresPerUnit);
            }
            while (pending.Count > 0) client.Send(pending.Dequeue()());
        }

        Transform FindBone(string name)
        {
            foreach (var t in skeletonRoot.GetComponentsInChildren<Transform>(true))
                if (t.name == name) return t;
            return null;
        }

        /// <summary>
        /// Start a transition from the context (>= context_frames frames) to the target's last frame. Whole takes
        /// are fine: the context is cut to the frames the model reads, the target to its last two.
        /// </summary>
        public void StartTransition(string contextBvh, string targetBvh, int frames, long? seed = null, bool deterministic = false)
        {
            StartMotion(() => RsmtMessages.BvhMotion(client.Cuts.Context(contextBvh)),
                        () => RsmtMessages.BvhMotion(client.Cuts.Target(targetBvh)), frames, seed, deterministic);
        }

        /// <summary>
        /// The same with poses in the model's axes and units (RsmtPoseRecorder.Last, RsmtPoseCapture), sent as pose arrays
        /// at `fps` (the model's when null; the server resamples others).
        /// </summary>
        public void StartTransition(IList<RsmtPose> context, IList<RsmtPose> target, int frames, long? seed = null,
                                    bool deterministic = false, double? fps = null)
        {
            StartMotion(RsmtMessages.PoseMotion(context, fps), RsmtMessages.PoseMotion(target, fps), frames, seed, deterministic);
        }

        /// <summary>Context: the recorder's last `contextFrames` samples (at least the model's context_frames, 10 by default).</summary>
        public void StartTransitionFromRecorder(IList<RsmtPose> target, int frames, int contextFrames = 10, long? seed = null,
                                                bool deterministic = false)
        {
            var context = recorder.Last(contextFrames);
            if (context.Count < contextFrames) Debug.LogWarning("RSMT: the recorder holds " + context.Count + " of " + contextFrames + " frames", this);
            StartTransition(context, target, frames, seed, deterministic, recorder.fps);
        }

        /// <summary>A start message with Motion payloads (RsmtMessages.BvhMotion / PoseMotion / RsmtPoseHistory.MotionJson).</summary>
        public void StartMotion(string contextMotionJson, string targetMotionJson, int frames, long? seed = null, bool deterministic = false)
        {
            StartMotion(() => contextMotionJson, () => targetMotionJson, frames, seed, deterministic);
        }

        void StartMotion(System.Func<string> contextMotionJson, System.Func<string> targetMotionJson, int frames, long? seed,
                         bool deterministic)
        {
            // Built when sent, so a style registered meanwhile (styleClip) is used, and hello's limits cut the motions.
            System.Func<string> message = () => RsmtMessages.Start(new RsmtStartOptions
            {
                Character = characterId, ContextJson = contextMotionJson(), TargetJson = targetMotionJson(),
                Frames = frames, StyleId = styleId, Seed = seed, Deterministic = deterministic,
                StyleStrength = styleStrength >= 0 ? (double?)styleStrength : null,
            });
            if (Ready && !string.IsNullOrEmpty(styleId)) client.Send(message());
            else pending.Enqueue(message);
        }

        /// <summary>A new target (and/or length, frames > 0) from the next frame on.</summary>
        public void Retarget(string targetBvh, int frames = 0)
        {
            if (client == null) return;
            var cuts = client.Cuts;  // null before hello: the target goes as it is
            string target = targetBvh == null ? null : RsmtMessages.BvhMotion(cuts == null ? targetBvh : cuts.Target(targetBvh));
            client.Retarget(characterId, target, frames);
        }

        /// <summary>A new target given as poses in the model's axes and units.</summary>
        public void Retarget(IList<RsmtPose> target, int frames = 0, double? fps = null)
        {
            if (client != null) client.Retarget(characterId, target == null ? null : RsmtMessages.PoseMotion(target, fps), frames);
        }

        public void Cancel()
        {
            if (client != null) client.Cancel(characterId);
        }

        void Update()
        {
            // At most 256 messages a frame: after a long stall the backlog drains over a few frames.
            if (client != null) client.Dispatch(Time.realtimeSinceStartupAsDouble, 256);
        }

        void LateUpdate()
        {
            RsmtPose pose;
            Playing = false;
            if (!Ready || !client.TrySample(characterId, Time.realtimeSinceStartupAsDouble, out pose)) return;
            Playing = !client.Buffer(characterId).Finished;
            for (int j = 0; j < bones.Length && j < pose.Rotations.Length; j++)
            {
                if (bones[j] == null) continue;
                var q = pose.Rotations[j];
                bones[j].localRotation = new Quaternion((float)q.X, (float)q.Y, (float)q.Z, (float)q.W);
            }
            if (bones.Length > 0 && bones[0] != null)
                bones[0].localPosition = new Vector3((float)pose.Root.X, (float)pose.Root.Y, (float)pose.Root.Z);
        }

        void OnDestroy()
        {
            if (client != null) client.Dispose();
            client = null;
        }
    }
}
