// Drives a Unity Humanoid from the model (and reads it back) through a hidden proxy of the model's rig.
//
// At Awake the bridge builds the model's skeleton under itself from the reference pose (clients/rig's
// STEM.tpose.json: rest offsets, T-pose), gives it a Humanoid Avatar (AvatarBuilder, bones mapped by
// humanBones below), and points RsmtCharacter and RsmtPoseRecorder at it. Every LateUpdate, after
// RsmtCharacter has posed the proxy, Unity's muscle-space retargeting (HumanPoseHandler) copies the proxy's
// human pose onto your character; while no transition plays it copies the other way, so the recorder samples
// your character's animation on the model's rig. Humanoid retargeting maps each rig's own T-pose onto the
// other's, so the rest-pose difference (bone axes, A- vs T-pose) is handled by the two Avatars.
using System;
using System.Collections.Generic;
using UnityEngine;

namespace Rsmt.Link.Unity
{
    [DefaultExecutionOrder(100)]
    public sealed class RsmtHumanoidBridge : MonoBehaviour
    {
        [Serializable]
        public struct BoneName
        {
            [Tooltip("HumanBodyBones name, e.g. LeftUpperArm")] public string human;
            [Tooltip("Model joint name, e.g. UpperArm_L")] public string joint;
        }

        [Tooltip("clients/rig/rsmt-default-rig.tpose.json")]
        public TextAsset referencePose;
        [Tooltip("Your character's Animator (Humanoid Avatar)")]
        public Animator hero;
        public RsmtCharacter character;
        public RsmtPoseRecorder recorder;
        public List<BoneName> humanBones = DefaultHumanBones();

        HumanPoseHandler proxyHandler, heroHandler;
        HumanPose pose;

        public Transform Proxy { get; private set; }

        public static List<BoneName> DefaultHumanBones()
        {
            var map = new List<BoneName>();
            foreach (var pair in new[]
            {
                "Hips", "Hips", "Spine", "Spine", "Chest", "Chest", "Neck", "Neck", "Head", "Head",
                "LeftShoulder", "Shoulder_L", "LeftUpperArm", "UpperArm_L", "LeftLowerArm", "LowerArm_L", "LeftHand", "Hand_L",
                "RightShoulder", "Shoulder_R", "RightUpperArm", "UpperArm_R", "RightLowerArm", "LowerArm_R", "RightHand", "Hand_R",
                "LeftUpperLeg", "UpperLeg_L", "LeftLowerLeg", "LowerLeg_L", "LeftFoot", "Foot_L", "LeftToes", "Toes_L",
                "RightUpperLeg", "UpperLeg_R", "RightLowerLeg", "LowerLeg_R", "RightFoot", "Foot_R", "RightToes", "Toes_R",
            }.Pairs())
                map.Add(new BoneName { human = pair.Key, joint = pair.Value });
            return map;
        }

        void Awake()
        {
            var reference = RsmtReferencePose.FromJson(referencePose.text);
            double s = RsmtCoordinates.MetresPerUnit(reference.Units);
            var root = new GameObject("RSMT proxy rig");
            root.transform.SetParent(transform, false);
            var joints = new Transform[reference.Names.Length];
            var skeleton = new List<SkeletonBone> { Bone(root.transform) };
            for (int j = 0; j < joints.Length; j++)
            {
                var t = new GameObject(reference.Names[j]).transform;
                t.SetParent(reference.Parents[j] < 0 ? root.transform : joints[reference.Parents[j]], false);
                var p = RsmtCoordinates.ModelToUnityPosition(reference.Parents[j] < 0 ? reference.Root : reference.Offsets[j], s);
                var q = RsmtCoordinates.ModelToUnityRotation(reference.LocalRotations[j]);
                t.localPosition = new Vector3((float)p.X, (float)p.Y, (float)p.Z);
                t.localRotation = new Quaternion((float)q.X, (float)q.Y, (float)q.Z, (float)q.W);
                joints[j] = t;
                skeleton.Add(Bone(t));
            }
            var human = new List<HumanBone>();
            foreach (var b in humanBones)
                human.Add(new HumanBone { humanName = b.human, boneName = b.joint, limit = new HumanLimit { useDefaultValues = true } });
            // The model importer's defaults for a Humanoid.
            var description = new HumanDescription
            {
                human = human.ToArray(), skeleton = skeleton.ToArray(), upperArmTwist = 0.5f, lowerArmTwist = 0.5f,
                upperLegTwist = 0.5f, lowerLegTwist = 0.5f, armStretch = 0.05f, legStretch = 0.05f, feetSpacing = 0f,
                hasTranslationDoF = false,
            };
            var avatar = AvatarBuilder.BuildHumanAvatar(root, description);
            if (!avatar.isValid) Debug.LogError("RSMT: the proxy's Humanoid Avatar is not valid; check humanBones", this);
            proxyHandler = new HumanPoseHandler(avatar, root.transform);
            heroHandler = new HumanPoseHandler(hero.avatar, hero.transform);
            Proxy = root.transform;
            if (character != null) character.skeletonRoot = Proxy;
            if (recorder != null)
            {
                recorder.skeletonRoot = Proxy;
                recorder.mode = RsmtPoseRecorder.Mode.ModelFrames;
                recorder.Bind(reference.Names, reference.Parents, s);
            }
        }

        static SkeletonBone Bone(Transform t)
        {
            return new SkeletonBone { name = t.name, position = t.localPosition, rotation = t.localRotation, scale = Vector3.one };
        }

        void LateUpdate()
        {
            if (character != null && character.Playing) Copy(proxyHandler, heroHandler);
            else Copy(heroHandler, proxyHandler);
        }

        /// <summary>Pose the proxy like the hero now (e.g. after AnimationClip.SampleAnimation, to read a target).</summary>
        public void CopyHeroToProxy() { Copy(heroHandler, proxyHandler); }

        void Copy(HumanPoseHandler from, HumanPoseHandler to)
        {
            from.GetHumanPose(ref pose);
            to.SetHumanPose(ref pose);
        }

        void OnDestroy()
        {
            if (proxyHandler != null) proxyHandler.Dispose();
            if (heroHandler != null) heroHandler.Dispose();
        }
    }

    static class PairsExtension
    {
        public static IEnumerable<KeyValuePair<string, string>> Pairs(this string[] flat)
        {
            for (int i = 0; i + 1 < flat.Length; i += 2) yield return new KeyValuePair<string, string>(flat[i], flat[i + 1]);
        }
    }
}
