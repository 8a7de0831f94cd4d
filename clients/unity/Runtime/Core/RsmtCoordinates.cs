// Conversion between the model's frame and Unity's.
//
// Model (hello.model.skeleton): right-handed, Y up, characters face +Z with their left on +X; units from
// skeleton.units (centimetres for the shipped models). Unity: left-handed, Y up, Z forward, X right, metres.
//
// We mirror across the YZ plane (negate X), the convention of glTF importers for Unity:
//   position:  (x, y, z)_model * s  ->  (-x, y, z)_unity          s = metres per model unit (0.01 for cm)
//   rotation:  (x, y, z, w)_model   ->  (x, -y, -z, w)_unity
// Up stays up and forward stays forward (+Z is Unity's Transform.forward), and since Unity's +X is a
// +Z-facing character's right, the model's left side (+X) lands on the character's left (-X): nothing
// is swapped left for right. Negating X is a mirror M (determinant -1), the handedness change itself; a
// rotation R becomes M R M, i.e. the axis a of the quaternion becomes -M a = (ax, -ay, -az) with the same
// angle. Applied to every local rotation and offset it converts a whole pose, since forward kinematics
// commutes with M. Both maps are their own inverse (up to the scale).
namespace Rsmt.Link
{
    public static class RsmtCoordinates
    {
        /// <summary>Metres per model unit for skeleton.units ("cm", "m", "mm", "in"); 0 when unknown.</summary>
        public static double MetresPerUnit(string units)
        {
            switch (units)
            {
                case "cm": case "centimeters": case "centimetres": return 0.01;
                case "m": case "meters": case "metres": return 1.0;
                case "mm": case "millimeters": case "millimetres": return 0.001;
                case "in": case "inches": return 0.0254;
                default: return 0.0;
            }
        }

        /// <summary>Null when the model declares the conventions these formulas assume, else why not.</summary>
        public static string CheckModel(RsmtModelInfo model)
        {
            if (model.UpAxis != "y" && model.UpAxis != "Y") return "up axis is '" + model.UpAxis + "', expected y";
            if (model.Handedness != "right") return "handedness is '" + model.Handedness + "', expected right";
            if (MetresPerUnit(model.Units) == 0) return "unknown units '" + model.Units + "'";
            return null;
        }

        public static RsmtVec3 ModelToUnityPosition(RsmtVec3 p, double metresPerUnit)
        {
            return new RsmtVec3(-p.X * metresPerUnit, p.Y * metresPerUnit, p.Z * metresPerUnit);
        }

        public static RsmtQuat ModelToUnityRotation(RsmtQuat q)
        {
            return new RsmtQuat(q.X, -q.Y, -q.Z, q.W);
        }

        public static RsmtVec3 UnityToModelPosition(RsmtVec3 p, double metresPerUnit)
        {
            return new RsmtVec3(-p.X / metresPerUnit, p.Y / metresPerUnit, p.Z / metresPerUnit);
        }

        public static RsmtQuat UnityToModelRotation(RsmtQuat q)
        {
            return new RsmtQuat(q.X, -q.Y, -q.Z, q.W);
        }

        public static RsmtPose ModelToUnityPose(RsmtPose pose, double metresPerUnit)
        {
            var output = new RsmtPose(pose.Rotations.Length) { Root = ModelToUnityPosition(pose.Root, metresPerUnit) };
            for (int j = 0; j < pose.Rotations.Length; j++) output.Rotations[j] = ModelToUnityRotation(pose.Rotations[j]);
            return output;
        }

        /// <summary>A Unity pose (e.g. captured from Transforms for a context) back in model units and axes.</summary>
        public static RsmtPose UnityToModelPose(RsmtPose pose, double metresPerUnit)
        {
            var output = new RsmtPose(pose.Rotations.Length) { Root = UnityToModelPosition(pose.Root, metresPerUnit) };
            for (int j = 0; j < pose.Rotations.Length; j++) output.Rotations[j] = UnityToModelRotation(pose.Rotations[j]);
            return output;
        }
    }
}
