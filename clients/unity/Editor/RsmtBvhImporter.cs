// Imports .bvh files as TextAssets, so a BVH take dropped into Assets/ can be assigned wherever the package takes
// motion text (RsmtCharacter.styleClip, the sample's context and target): no renaming to .txt. The text is kept
// as it is; whole takes are fine (the clients cut them to what the model reads).
using System.IO;
using UnityEditor.AssetImporters;
using UnityEngine;

namespace Rsmt.Link.Importers
{
    [ScriptedImporter(1, "bvh")]
    public sealed class RsmtBvhImporter : ScriptedImporter
    {
        public override void OnImportAsset(AssetImportContext ctx)
        {
            var text = new TextAsset(File.ReadAllText(ctx.assetPath));
            ctx.AddObjectToAsset("bvh", text);
            ctx.SetMainObject(text);
        }
    }
}
