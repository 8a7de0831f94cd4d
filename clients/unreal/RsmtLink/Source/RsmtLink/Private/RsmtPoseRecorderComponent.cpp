#include "RsmtPoseRecorderComponent.h"

#include "Components/SkeletalMeshComponent.h"
#include "Engine/World.h"
#include "GameFramework/Actor.h"
#include "Misc/FileHelper.h"
#include "Misc/Paths.h"

#include "RsmtConvert.h"

DEFINE_LOG_CATEGORY_STATIC(LogRsmtRecorder, Log, All);

URsmtPoseRecorderComponent::URsmtPoseRecorderComponent()
{
	PrimaryComponentTick.bCanEverTick = true;
	PrimaryComponentTick.TickGroup = TG_PostUpdateWork;  // after the animation has posed the mesh
}

void URsmtPoseRecorderComponent::BeginPlay()
{
	Super::BeginPlay();
	if (Mesh == nullptr && GetOwner() != nullptr)
	{
		Mesh = GetOwner()->FindComponentByClass<USkeletalMeshComponent>();
	}
	FString Text;
	const FString Path = FPaths::Combine(FPaths::ProjectContentDir(), ReferencePoseFile);
	std::string Error;
	if (!FFileHelper::LoadFileToString(Text, *Path) || !rsmt::ParseReferencePose(std::string(TCHAR_TO_UTF8(*Text)), Reference, &Error))
	{
		UE_LOG(LogRsmtRecorder, Error, TEXT("RSMT recorder: cannot read the reference pose %s: %s"), *Path, UTF8_TO_TCHAR(Error.c_str()));
		return;
	}
	CmPerUnit = rsmt::CentimetresPerUnit(Reference.units);
	History = std::make_unique<rsmt::PoseHistory>(Fps, FMath::Max(Capacity, 2));
	BoneIndices.Reset();
	for (const std::string& Joint : Reference.names)
	{
		const FName JointName(UTF8_TO_TCHAR(Joint.c_str()));
		const FName* Mapped = BoneMap.Find(JointName);
		const int32 Index = Mesh != nullptr ? Mesh->GetBoneIndex(Mapped != nullptr ? *Mapped : JointName) : INDEX_NONE;
		if (Index == INDEX_NONE)
		{
			UE_LOG(LogRsmtRecorder, Warning, TEXT("RSMT recorder: no bone for joint %s"), *JointName.ToString());
		}
		BoneIndices.Add(Index);
	}
}

bool URsmtPoseRecorderComponent::ReadComponentSpace(std::vector<rsmt::Quat>& Rotations, rsmt::Vec3& Root) const
{
	if (Mesh == nullptr || BoneIndices.Num() == 0 || BoneIndices[0] == INDEX_NONE)
	{
		return false;
	}
	Rotations.assign(static_cast<size_t>(BoneIndices.Num()), rsmt::Quat());
	for (int32 J = 0; J < BoneIndices.Num(); ++J)
	{
		if (BoneIndices[J] == INDEX_NONE)
		{
			continue;
		}
		// Component space: relative to the mesh component, not the world.
		const FQuat Q = Mesh->GetBoneTransform(BoneIndices[J], FTransform::Identity).GetRotation();
		Rotations[static_cast<size_t>(J)] = rsmt::Quat{Q.X, Q.Y, Q.Z, Q.W};
	}
	const FVector P = Mesh->GetBoneTransform(BoneIndices[0], FTransform::Identity).GetLocation();
	Root = rsmt::Vec3{P.X, P.Y, P.Z};
	return true;
}

void URsmtPoseRecorderComponent::CaptureReference()
{
	std::vector<rsmt::Quat> World;
	rsmt::Vec3 Root;
	if (!ReadComponentSpace(World, Root) || Reference.worldRotations.empty())
	{
		UE_LOG(LogRsmtRecorder, Error, TEXT("RSMT recorder: CaptureReference needs the mesh and the reference pose"));
		return;
	}
	Offsets = rsmt::RetargetOffsets(World, Reference.worldRotations);
}

void URsmtPoseRecorderComponent::TickComponent(float DeltaTime, ELevelTick TickType, FActorComponentTickFunction* ThisTickFunction)
{
	Super::TickComponent(DeltaTime, TickType, ThisTickFunction);
	std::vector<rsmt::Quat> World;
	rsmt::Vec3 Root;
	if (!History || !ReadComponentSpace(World, Root))
	{
		return;
	}
	rsmt::Pose Pose;
	if (bRetargetFromReference)
	{
		if (Offsets.empty())
		{
			return;  // CaptureReference first
		}
		Pose = rsmt::FromUnrealWorld(World, Root, Reference.parents, Offsets, CmPerUnit, RootScale);
	}
	else
	{
		// The skeleton has the model's joint frames: local = inverse(parent) * joint, along the model's parents.
		std::vector<rsmt::Quat> Local(World.size());
		for (size_t J = 0; J < World.size(); ++J)
		{
			const int P = Reference.parents[J];
			Local[J] = P < 0 ? World[J] : rsmt::Multiply(rsmt::Inverse(World[static_cast<size_t>(P)]), World[J]);
		}
		Pose = rsmt::FromUnrealLocal(Local, Root, CmPerUnit);
	}
	History->Add(GetWorld()->GetTimeSeconds(), Pose);
}

FString URsmtPoseRecorderComponent::MotionJson(int32 Frames) const
{
	if (!History || History->Count() == 0)
	{
		return FString();
	}
	return FString(UTF8_TO_TCHAR(History->MotionJson(Frames).c_str()));
}

int32 URsmtPoseRecorderComponent::RecordedFrames() const
{
	return History ? History->Count() : 0;
}
