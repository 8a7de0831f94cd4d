// Which Transform drives each model joint: an asset you create with Assets > Create > RSMT > Joint Map.
using System;
using System.Collections.Generic;
using UnityEngine;

namespace Rsmt.Link.Unity
{
    [CreateAssetMenu(menuName = "RSMT/Joint Map", fileName = "RsmtJointMap")]
    public sealed class RsmtJointMap : ScriptableObject
    {
        [Serializable]
        public struct Entry
        {
            [Tooltip("Joint name as GET /v1/model lists it (e.g. Hips)")] public string modelJoint;
            [Tooltip("Name of the Transform under the skeleton root (e.g. mixamorig:Hips)")] public string transformName;
        }

        public List<Entry> entries = new List<Entry>();
        [Tooltip("Joints without an entry are looked up by their own name")]
        public bool matchSameNames = true;

        /// <summary>One Transform (or null) per model joint, searched under root by name.</summary>
        public Transform[] Resolve(Transform root, IList<string> modelJoints, List<string> missing)
        {
            var byName = new Dictionary<string, Transform>();
            foreach (var t in root.GetComponentsInChildren<Transform>(true))
            {
                if (!byName.ContainsKey(t.name)) byName.Add(t.name, t);
            }
            var map = new Dictionary<string, string>();
            foreach (var e in entries)
            {
                if (!string.IsNullOrEmpty(e.modelJoint)) map[e.modelJoint] = e.transformName;
            }
            return RsmtJointBinding.Resolve(modelJoints, map, matchSameNames,
                name => { Transform t; return byName.TryGetValue(name, out t) ? t : null; }, missing);
        }
    }
}
