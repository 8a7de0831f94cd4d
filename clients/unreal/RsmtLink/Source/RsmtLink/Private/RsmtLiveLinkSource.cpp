#include "RsmtLiveLinkSource.h"

#include "ILiveLinkClient.h"
#include "Roles/LiveLinkAnimationRole.h"
#include "Roles/LiveLinkAnimationTypes.h"

void FRsmtLiveLinkSource::ReceiveClient(ILiveLinkClient* InClient, FGuid InSourceGuid)
{
	Client = InClient;
	SourceGuid = InSourceGuid;
}

bool FRsmtLiveLinkSource::RequestSourceShutdown()
{
	Client = nullptr;
	return true;
}

FText FRsmtLiveLinkSource::GetSourceStatus() const
{
	return bHasSkeleton ? NSLOCTEXT("RsmtLink", "Streaming", "Streaming") : NSLOCTEXT("RsmtLink", "Waiting", "Waiting for hello");
}

void FRsmtLiveLinkSource::PushSkeleton(FName Subject, const TArray<FName>& BoneNames, const TArray<int32>& BoneParents)
{
	if (Client == nullptr)
	{
		return;
	}
	FLiveLinkStaticDataStruct StaticData(FLiveLinkSkeletonStaticData::StaticStruct());
	FLiveLinkSkeletonStaticData& Skeleton = *StaticData.Cast<FLiveLinkSkeletonStaticData>();
	Skeleton.SetBoneNames(BoneNames);
	Skeleton.SetBoneParents(BoneParents);
	Client->PushSubjectStaticData_AnyThread(FLiveLinkSubjectKey(SourceGuid, Subject), ULiveLinkAnimationRole::StaticClass(),
		MoveTemp(StaticData));
	bHasSkeleton = true;
}

void FRsmtLiveLinkSource::PushPose(FName Subject, const TArray<FTransform>& Transforms)
{
	if (Client == nullptr || !bHasSkeleton)
	{
		return;
	}
	FLiveLinkFrameDataStruct FrameData(FLiveLinkAnimationFrameData::StaticStruct());
	FLiveLinkAnimationFrameData& Animation = *FrameData.Cast<FLiveLinkAnimationFrameData>();
	Animation.WorldTime = FLiveLinkWorldTime(FPlatformTime::Seconds());
	Animation.Transforms = Transforms;
	Client->PushSubjectFrameData_AnyThread(FLiveLinkSubjectKey(SourceGuid, Subject), MoveTemp(FrameData));
}
