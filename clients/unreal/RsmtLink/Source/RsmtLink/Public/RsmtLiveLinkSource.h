// A Live Link source that RsmtLinkComponent feeds: one subject per component, skeleton from the
// server's hello (static data), one frame per tick from the jitter buffer (frame data).
// Use it in an Animation Blueprint with the "Live Link Pose" node and the component's SubjectName.
#pragma once

#include "CoreMinimal.h"
#include "ILiveLinkSource.h"

class ILiveLinkClient;

class RSMTLINK_API FRsmtLiveLinkSource : public ILiveLinkSource
{
public:
	explicit FRsmtLiveLinkSource(const FString& InServer) : Server(InServer) {}

	// ILiveLinkSource
	virtual void ReceiveClient(ILiveLinkClient* InClient, FGuid InSourceGuid) override;
	virtual bool IsSourceStillValid() const override { return Client != nullptr; }
	virtual bool RequestSourceShutdown() override;
	virtual FText GetSourceType() const override { return NSLOCTEXT("RsmtLink", "SourceType", "RSMT"); }
	virtual FText GetSourceMachineName() const override { return FText::FromString(Server); }
	virtual FText GetSourceStatus() const override;

	// Bone names and parent indices, in the model's joint order. Clears the subject's buffered frames.
	void PushSkeleton(FName Subject, const TArray<FName>& BoneNames, const TArray<int32>& BoneParents);
	// Parent-relative bone transforms in the same order (Unreal axes and units).
	void PushPose(FName Subject, const TArray<FTransform>& Transforms);

private:
	ILiveLinkClient* Client = nullptr;
	FGuid SourceGuid;
	FString Server;
	bool bHasSkeleton = false;
};
