// Records a character's recent poses for `start`/`retarget` contexts and targets: reads the bound bones every
// LateUpdate (after animation, after RsmtCharacter and RsmtHumanoidBridge), converts them to the model's axes
// (RsmtPoseCapture) and keeps them resampled to the model's frame rate (RsmtPoseHistory).
//
// Modes:
// - ModelFrames: the bones have the model's joint frames (the rig from clients/rig, or the proxy that
//   RsmtHumanoidBridge builds): local rotations convert exactly.
// - RetargetFromReference: any rig. Put it in the model's reference pose (the T-pose of clients/rig) and call
//   CaptureReference() once (context menu, or from code at startup before the Animator moves it); later poses
//   are carried over bone by bone as rotations away from that reference (see RsmtPoseCapture).
using System.Collections.Generic;
using UnityEngine;

namespace Rsmt.Link.Unity
{
    [DefaultExecutionOrder(200)]
    public sealed class RsmtPoseRecorder : MonoBehaviour
    {
        public enum Mode { ModelFrames, RetargetFromReference }

        [Tooltip("clients/rig/rsmt-default-rig.tpose.json: joint names and parents (and the T-pose for RetargetFromReference). " +
                 "Without it, RsmtCharacter binds the recorder from the server's hello.")]
        public TextAsset referencePose;
        public Mode mode = Mode.ModelFrames;
        public RsmtJointMap jointMap;
        [Tooltip("Top of the bone hierarchy (bones are searched under it by name)")]
        public Transform skeletonRoot;
        [Tooltip("RetargetFromReference: rotations and the root position are taken relative to this (default: this object)")]
        public Transform space;
        public float fps = 30f;
        [Tooltip("Samples kept (at fps): at least the model's context_frames")]
        public int capacity = 60;
        public float metresPerUnit = 0.01f;
        [Tooltip("RetargetFromReference: model hip height / this rig's hip height")]
        public float rootScale = 1f;

        RsmtPoseHistory history;
        RsmtReferencePose reference;
        Transform[] bones;
        int[] parents;
        RsmtQuat[] offsets;

        public bool Bound { get { return bones != null; } }
        public RsmtPoseHistory History { get { return history; } }

        void Awake()
        {
            if (referencePose != null)
            {
                reference = RsmtReferencePose.FromJson(referencePose.text);
                Bind(reference.Names, reference.Parents, RsmtCoordinates.MetresPerUnit(reference.Units));
            }
        }

        /// <summary>Bind the model's joints (names in skeleton order, parents) to the bones under skeletonRoot.</summary>
        public void Bind(IList<string> names, IList<int> jointParents, double unitsToMetres)
        {
            var missing = new List<string>();
            var root = skeletonRoot != null ? skeletonRoot : transform;
            bones = jointMap != null ? jointMap.Resolve(root, names, missing)
                                     : RsmtJointBinding.Resolve(names, null, true, n => Find(root, n), missing);
            parents = new int[jointParents.Count];
            jointParents.CopyTo(parents, 0);
            if (unitsToMetres > 0) metresPerUnit = (float)unitsToMetres;
            history = new RsmtPoseHistory(fps, Mathf.Max(capacity, 2));
            if (missing.Count > 0) Debug.LogWarning("RSMT recorder: no bone for joint(s) " + string.Join(", ", missing.ToArray()), this);
        }

        static Transform Find(Transform root, string name)
        {
            foreach (var t in root.GetComponentsInChildren<Transform>(true))
                if (t.name == name) return t;
            return null;
        }

        /// <summary>RetargetFromReference: the rig stands in the model's reference pose (T-pose) now.</summary>
        [ContextMenu("Capture reference pose")]
        public void CaptureReference()
        {
            if (!Bound || reference == null)
            {
                Debug.LogError("RSMT recorder: CaptureReference needs referencePose (the model's T-pose)", this);
                return;
            }
            offsets = RsmtPoseCapture.RetargetOffsets(WorldRotations(), reference.WorldRotations);
        }

        RsmtQuat[] WorldRotations()
        {
            var s = space != null ? space : transform;
            var output = new RsmtQuat[bones.Length];
            for (int j = 0; j < bones.Length; j++)
                output[j] = bones[j] == null ? RsmtQuat.Identity : Q(Quaternion.Inverse(s.rotation) * bones[j].rotation);
            return output;
        }

        /// <summary>The bones' pose now, in the model's axes and units (null before Bind, or before CaptureReference).</summary>
        public RsmtPose CurrentPose()
        {
            if (!Bound || bones.Length == 0 || bones[0] == null) return null;
            if (mode == Mode.ModelFrames)
            {
                var local = new RsmtQuat[bones.Length];
                for (int j = 0; j < bones.Length; j++) local[j] = bones[j] == null ? RsmtQuat.Identity : Q(bones[j].localRotation);
                return RsmtPoseCapture.FromUnityLocal(local, V(bones[0].localPosition), metresPerUnit);
            }
            if (offsets == null) return null;
            var s = space != null ? space : transform;
            return RsmtPoseCapture.FromUnityWorld(WorldRotations(), V(s.InverseTransformPoint(bones[0].position)), parents, offsets,
                                                  metresPerUnit, rootScale);
        }

        /// <summary>The newest samples at fps, oldest first (model axes): a context is Last(context_frames).</summary>
        public List<RsmtPose> Last(int frames)
        {
            return history == null ? new List<RsmtPose>() : history.Last(frames);
        }

        void LateUpdate()
        {
            var pose = CurrentPose();
            if (pose != null) history.Add(Time.timeAsDouble, pose);
        }

        static RsmtQuat Q(Quaternion q) { return new RsmtQuat(q.x, q.y, q.z, q.w); }
        static RsmtVec3 V(Vector3 v) { return new RsmtVec3(v.x, v.y, v.z); }
    }
}
