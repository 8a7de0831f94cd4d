// URsmtLinkComponent: drives one character from an RSMT server.
//
// Connects to ws://.../v1/stream (IWebSocket), reassembles and decodes every message with RsmtCore,
// converts poses to Unreal axes (RsmtConvert.h), plays them at the model's frame rate through a
// jitter buffer, and pushes the current pose to a Live Link subject each tick. All callbacks run
// on the game thread (IWebSocket and the HTTP module dispatch there).
#pragma once

#include "Components/ActorComponent.h"
#include "CoreMinimal.h"

#include <string>

// RsmtCore headers are plain C++ (no Unreal types); they are included here so the members below are complete.
#include "RsmtFailover.h"
#include "RsmtJitterBuffer.h"
#include "RsmtMotionCut.h"
#include "RsmtProtocol.h"
#include "RsmtReassembler.h"

#include "RsmtLinkComponent.generated.h"

class IWebSocket;
class FRsmtLiveLinkSource;

DECLARE_DYNAMIC_MULTICAST_DELEGATE(FRsmtConnectedEvent);
DECLARE_DYNAMIC_MULTICAST_DELEGATE_OneParam(FRsmtStyleEvent, const FString&, StyleId);
DECLARE_DYNAMIC_MULTICAST_DELEGATE_TwoParams(FRsmtEndEvent, const FString&, Reason, int32, Frames);
DECLARE_DYNAMIC_MULTICAST_DELEGATE_TwoParams(FRsmtErrorEvent, const FString&, Code, const FString&, Message);

UCLASS(ClassGroup = (Animation), meta = (BlueprintSpawnableComponent))
class RSMTLINK_API URsmtLinkComponent : public UActorComponent
{
	GENERATED_BODY()

public:
	URsmtLinkComponent();

	/** Service base URL (http://host:port); the stream URL is derived from it. */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	FString ServerUrl = TEXT("http://127.0.0.1:8000");

	/** API key, when the server has keys on (sent as X-API-Key). */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	FString ApiKey;

	/** Binary float32 frames (smaller, faster) instead of JSON. */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	bool bBinaryFrames = true;

	/** Live Link subject to use in the Animation Blueprint's "Live Link Pose" node. */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	FName SubjectName = TEXT("RSMT");

	/** Character id on the connection. */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	FString CharacterId = TEXT("hero");

	/** Seconds frames wait in the jitter buffer before they play (0.05 - 0.3 is typical). */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT", meta = (ClampMin = "0.0", ClampMax = "2.0"))
	float BufferDelaySeconds = 0.1f;

	/**
	 * Failover: when the connection is lost (a replica behind the load balancer died or drained; not on 1008/1009),
	 * connect again to the same URL with backoff and resume the character from the frames it received last
	 * (README, "Failover across replicas"). Styles registered with RegisterStyle are registered again when needed.
	 */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	bool bFailover = false;

	/** Connection attempts after a loss (0.25 s doubling up to 4 s between them). */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT", meta = (ClampMin = "1"))
	int32 ReconnectAttempts = 8;

	/** The style used by StartTransition (set by RegisterStyle, or paste an id). */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT")
	FString StyleId;

	/**
	 * How far StartTransition moves the style from the model's neutral style (0 to 4; 1: as encoded). Below 0: not
	 * sent, the server's setting (1 unless RSMT_STYLE_STRENGTH).
	 */
	UPROPERTY(EditAnywhere, BlueprintReadWrite, Category = "RSMT", meta = (ClampMin = "-1.0", ClampMax = "4.0"))
	float StyleStrength = -1.0f;

	UPROPERTY(BlueprintAssignable, Category = "RSMT")
	FRsmtConnectedEvent OnConnected;
	UPROPERTY(BlueprintAssignable, Category = "RSMT")
	FRsmtStyleEvent OnStyleRegistered;
	UPROPERTY(BlueprintAssignable, Category = "RSMT")
	FRsmtEndEvent OnTransitionEnded;
	UPROPERTY(BlueprintAssignable, Category = "RSMT")
	FRsmtErrorEvent OnError;

	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void Connect();
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void Disconnect();
	/**
	 * POST /v1/styles with a BVH clip; OnStyleRegistered gives the id (also stored in StyleId). Retries 429/503.
	 * Once connected (after OnConnected), a clip longer than the model reads is cut to its middle (logged once).
	 */
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void RegisterStyle(const FString& StyleBvh, const FString& Name);
	/**
	 * POST /v1/styles with 1 to 5 BVH clips of one style, encoded together into one style (the same clips in any order
	 * get the same id); each clip is cut as RegisterStyle cuts one. OnStyleRegistered gives the id, as for one clip.
	 */
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void RegisterStyleClips(const TArray<FString>& StyleBvhs, const FString& Name);
	/**
	 * Start a transition from the context (>= context_frames frames) to the target's last frame, in Frames frames.
	 * Whole takes are fine: the context is cut to the frames the model reads, the target to its last two.
	 */
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void StartTransition(const FString& ContextBvh, const FString& TargetBvh, int32 Frames, int32 Seed = -1,
		bool bDeterministic = false);
	/** A new target and/or length from the next frame on (Frames <= 0 keeps the length). */
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void Retarget(const FString& TargetBvh, int32 Frames = 0);
	/**
	 * StartTransition with Motion payloads (JSON): URsmtPoseRecorderComponent::MotionJson for poses read from a mesh,
	 * or BvhMotion(BvhText). Context: >= context_frames frames; target: its last frame (and the one before it).
	 */
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void StartTransitionMotion(const FString& ContextMotionJson, const FString& TargetMotionJson, int32 Frames, int32 Seed = -1,
		bool bDeterministic = false);
	/** Retarget with a Motion payload (empty: keep the target, change the length only). */
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void RetargetMotion(const FString& TargetMotionJson, int32 Frames = 0);
	/** BVH text as a Motion payload ({"bvh": ...}). */
	UFUNCTION(BlueprintPure, Category = "RSMT")
	static FString BvhMotion(const FString& BvhText);
	UFUNCTION(BlueprintCallable, Category = "RSMT")
	void Cancel();
	UFUNCTION(BlueprintPure, Category = "RSMT")
	bool IsConnected() const;

	virtual void TickComponent(float DeltaTime, ELevelTick TickType, FActorComponentTickFunction* ThisTickFunction) override;

protected:
	virtual void BeginPlay() override;
	virtual void EndPlay(const EEndPlayReason::Type EndPlayReason) override;

private:
	void HandleConnected();
	void HandleConnectionError(const FString& Error);
	void HandleClosed(int32 StatusCode, const FString& Reason, bool bWasClean);
	void HandleRawMessage(const void* Data, SIZE_T Size, SIZE_T BytesRemaining);
	void HandleMessage(rsmt::Message& Message);
	void SendText(const std::string& Text);
	void PostStyle(const std::string& Body, int32 Attempt, const std::string& Then = std::string());
	void OpenSocket();
	void CloseSocket();
	void ScheduleReconnect(const FString& Why);

	TSharedPtr<IWebSocket> Socket;
	TSharedPtr<FRsmtLiveLinkSource> Source;
	rsmt::Session Session;
	rsmt::MessageAssembler Assembler;  // 1 MiB per message at most
	rsmt::JitterBuffer Buffer;
	std::string PendingStart;  // a start requested before hello arrived
	TFunction<void()> PendingBvhStart;  // a StartTransition before hello: cut and sent when hello has come
	rsmt::MotionCutter Cuts{rsmt::MotionLimits()};  // what hello's model reads (passes motions through before hello)
	rsmt::Failover Failover;   // resume state (bFailover)
	bool bResumeOnHello = false;
	int32 ReconnectAttempt = 0;
	FTimerHandle ReconnectTimer;
	TArray<FTransform> RestTransforms;
	double CmPerUnit = 1.0;
};
