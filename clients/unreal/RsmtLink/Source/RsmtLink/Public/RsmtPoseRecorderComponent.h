// URsmtPoseRecorderComponent: records a skeletal mesh's recent poses as the model's poses, for the context (and
// target) of URsmtLinkComponent::StartTransitionMotion / RetargetMotion.
//
// A thin wrapper: each tick (after animation, TG_PostUpdateWork) it reads the mapped bones' component-space
// transforms from the mesh and hands them to RsmtCore (RsmtPoseCapture.h: axis conversion, optional reference-pose
// retargeting, resampling to the model's fps), which the repository's tests build and check with g++.
//
// Modes:
// - model frames (default): the mesh's skeleton has the model's joint frames: the rig imported from clients/rig,
//   e.g. a hidden RSMT mesh that an IK Retargeter ("Retarget Pose From Mesh") drives from your character.
// - bRetargetFromReference: any skeleton; stand it in the model's reference pose (clients/rig's T-pose) and call
//   CaptureReference once; later poses are carried over as rotations away from that reference.
#pragma once

#include "Components/ActorComponent.h"
#include "CoreMinimal.h"

#include <memory>
#include <vector>

#include "RsmtPoseCapture.h"

#include "RsmtPoseRecorderComponent.generated.h"

class USkeletalMeshComponent;

UCLASS(ClassGroup = (Animation), meta = (BlueprintSpawnableComponent))
class RSMTLINK_API URsmtPoseRecorderComponent : public UActorComponent
{
	GENERATED_BODY()

public:
	URsmtPoseRecorderComponent();

	/** The mesh to read (default: the owner's first skeletal mesh component). */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	TObjectPtr<USkeletalMeshComponent> Mesh;

	/** clients/rig/rsmt-default-rig.tpose.json, relative to the project's Content folder: joints, parents, T-pose. */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	FString ReferencePoseFile = TEXT("RSMT/rsmt-default-rig.tpose.json");

	/** Model joint -> bone name where they differ (others: the joint's own name). */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	TMap<FName, FName> BoneMap;

	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	bool bRetargetFromReference = false;

	/** Samples per second (the model's fps) and how many are kept (at least the model's context_frames). */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	float Fps = 30.0f;
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	int32 Capacity = 60;

	/** Retarget mode: model hip height / this skeleton's hip height. */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	float RootScale = 1.0f;

	/** Retarget mode: the mesh stands in the model's reference pose (T-pose) now. */
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void CaptureReference();

	/** The newest Frames samples as a Motion payload (pose arrays); empty until something was recorded. */
	UFUNCTION(BlueprintPure, Category = "RSMT")
	FString MotionJson(int32 Frames = 10) const;

	UFUNCTION(BlueprintPure, Category = "RSMT")
	int32 RecordedFrames() const;

	virtual void TickComponent(float DeltaTime, ELevelTick TickType, FActorComponentTickFunction* ThisTickFunction) override;

protected:
	virtual void BeginPlay() override;

private:
	bool ReadComponentSpace(std::vector<rsmt::Quat>& Rotations, rsmt::Vec3& Root) const;

	rsmt::ReferencePose Reference;
	std::unique_ptr<rsmt::PoseHistory> History;
	TArray<int32> BoneIndices;  // per model joint, INDEX_NONE when unmapped
	std::vector<rsmt::Quat> Offsets;
	double CmPerUnit = 1.0;
};
