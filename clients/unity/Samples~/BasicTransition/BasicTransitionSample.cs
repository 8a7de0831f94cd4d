// Sample: press Space to start a transition from the context clip to the target clip; press R to retarget it
// to the second target while it plays. Put it next to an RsmtCharacter and assign .bvh files (imported as
// TextAssets by the package's RsmtBvhImporter); whole takes are fine, they are cut to what the model reads.
using UnityEngine;
using Rsmt.Link.Unity;

public sealed class BasicTransitionSample : MonoBehaviour
{
    public RsmtCharacter character;
    public TextAsset context;   // >= context_frames frames of the character's recent motion
    public TextAsset target;    // its last frame is the pose to arrive at
    public TextAsset otherTarget;
    [Range(1, 120)] public int frames = 40;

    void Update()
    {
        if (Input.GetKeyDown(KeyCode.Space)) character.StartTransition(context.text, target.text, frames);
        if (Input.GetKeyDown(KeyCode.R) && otherTarget != null) character.Retarget(otherTarget.text, frames / 2);
    }
}
