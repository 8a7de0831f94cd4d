// Matching the model's joints to a rig's bones by name (what RsmtJointMap does over a Transform hierarchy).
using System;
using System.Collections.Generic;

namespace Rsmt.Link
{
    public static class RsmtJointBinding
    {
        /// <summary>
        /// For each model joint, the bone found by `find`: the mapped name when `map` has one, else (when
        /// `sameNames`) the joint's own name, tried as written and without a namespace prefix ("mixamorig:Hips").
        /// Unbound joints get default(T); `missing` lists them.
        /// </summary>
        public static T[] Resolve<T>(IList<string> modelJoints, IDictionary<string, string> map, bool sameNames,
                                     Func<string, T> find, List<string> missing) where T : class
        {
            var bound = new T[modelJoints.Count];
            for (int i = 0; i < modelJoints.Count; i++)
            {
                string joint = modelJoints[i];
                string name;
                T bone = null;
                if (map != null && map.TryGetValue(joint, out name) && !string.IsNullOrEmpty(name)) bone = find(name);
                else if (sameNames)
                {
                    bone = find(joint);
                    int colon = joint.LastIndexOf(':');
                    if (bone == null && colon >= 0) bone = find(joint.Substring(colon + 1));
                }
                bound[i] = bone;
                if (bone == null && missing != null) missing.Add(joint);
            }
            return bound;
        }
    }
}
