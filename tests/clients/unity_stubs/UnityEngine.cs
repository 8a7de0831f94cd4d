// Test-only stand-in for the few UnityEngine types the RSMT Unity package uses, so that mcs can type-check
// Runtime/Unity/*.cs and the sample without Unity. Signatures follow Unity's; bodies do nothing useful.
using System;
using System.Collections.Generic;

namespace UnityEngine
{
    public class Object
    {
        public string name = "";
    }

    public class Component : Object
    {
        public Transform transform { get { return null; } }
        public T[] GetComponentsInChildren<T>(bool includeInactive) { return new T[0]; }
    }

    public class Behaviour : Component { public bool enabled = true; }
    public class MonoBehaviour : Behaviour { }
    public class ScriptableObject : Object { }

    public class Transform : Component
    {
        public Quaternion localRotation;
        public Vector3 localPosition;
        public Quaternion rotation;
        public Vector3 position;
        public void SetParent(Transform parent, bool worldPositionStays) { }
        public Vector3 InverseTransformPoint(Vector3 position) { return position; }
    }

    public sealed class GameObject : Object
    {
        public GameObject(string name) { this.name = name; }
        public Transform transform { get { return null; } }
    }

    public struct Vector3
    {
        public float x, y, z;
        public Vector3(float x, float y, float z) { this.x = x; this.y = y; this.z = z; }
        public static Vector3 one { get { return new Vector3(1, 1, 1); } }
    }

    public struct Quaternion
    {
        public float x, y, z, w;
        public Quaternion(float x, float y, float z, float w) { this.x = x; this.y = y; this.z = z; this.w = w; }
        public static Quaternion Inverse(Quaternion q) { return q; }
        public static Quaternion operator *(Quaternion a, Quaternion b) { return a; }
    }

    public static class Mathf
    {
        public static int Max(int a, int b) { return a > b ? a : b; }
    }

    public class Avatar : Object { public bool isValid { get { return true; } } }
    public class Animator : Behaviour { public Avatar avatar; }
    public struct HumanLimit { public bool useDefaultValues { get; set; } }
    public struct HumanBone { public string humanName; public string boneName; public HumanLimit limit; }
    public struct SkeletonBone { public string name; public Vector3 position; public Quaternion rotation; public Vector3 scale; }

    public struct HumanDescription
    {
        public HumanBone[] human;
        public SkeletonBone[] skeleton;
        public float upperArmTwist { get; set; }
        public float lowerArmTwist { get; set; }
        public float upperLegTwist { get; set; }
        public float lowerLegTwist { get; set; }
        public float armStretch { get; set; }
        public float legStretch { get; set; }
        public float feetSpacing { get; set; }
        public bool hasTranslationDoF { get; set; }
    }

    public static class AvatarBuilder
    {
        public static Avatar BuildHumanAvatar(GameObject go, HumanDescription humanDescription) { return new Avatar(); }
    }

    public struct HumanPose { public Vector3 bodyPosition; public Quaternion bodyRotation; public float[] muscles; }

    public class HumanPoseHandler : IDisposable
    {
        public HumanPoseHandler(Avatar avatar, Transform root) { }
        public void GetHumanPose(ref HumanPose humanPose) { }
        public void SetHumanPose(ref HumanPose humanPose) { }
        public void Dispose() { }
    }

    public class TextAsset : Object
    {
        public string text = "";
        public TextAsset() { }
        public TextAsset(string text) { this.text = text; }
    }

    public static class Debug
    {
        public static void Log(object message) { }
        public static void LogWarning(object message, Object context) { }
        public static void LogError(object message, Object context) { }
    }

    public static class Time
    {
        public static double realtimeSinceStartupAsDouble { get { return 0; } }
        public static double timeAsDouble { get { return 0; } }
    }

    public static class Application
    {
        public static bool runInBackground { get; set; }
    }

    public enum KeyCode { Space = 32, R = 114 }

    public static class Input
    {
        public static bool GetKeyDown(KeyCode key) { return false; }
    }

    [AttributeUsage(AttributeTargets.Field)]
    public sealed class HeaderAttribute : Attribute { public HeaderAttribute(string header) { } }

    [AttributeUsage(AttributeTargets.Field)]
    public sealed class TooltipAttribute : Attribute { public TooltipAttribute(string tooltip) { } }

    [AttributeUsage(AttributeTargets.Field)]
    public sealed class RangeAttribute : Attribute { public RangeAttribute(float min, float max) { } }

    [AttributeUsage(AttributeTargets.Class)]
    public sealed class CreateAssetMenuAttribute : Attribute
    {
        public string menuName { get; set; }
        public string fileName { get; set; }
    }

    [AttributeUsage(AttributeTargets.Class)]
    public sealed class DefaultExecutionOrderAttribute : Attribute { public DefaultExecutionOrderAttribute(int order) { } }

    [AttributeUsage(AttributeTargets.Method)]
    public sealed class ContextMenuAttribute : Attribute { public ContextMenuAttribute(string itemName) { } }
}
