#include "RsmtLinkComponent.h"

#include "Features/IModularFeatures.h"
#include "HttpModule.h"
#include "ILiveLinkClient.h"
#include "IWebSocket.h"
#include "Interfaces/IHttpRequest.h"
#include "Interfaces/IHttpResponse.h"
#include "TimerManager.h"
#include "WebSocketsModule.h"
#include "Engine/World.h"

#include "RsmtConvert.h"
#include "RsmtJitterBuffer.h"
#include "RsmtJson.h"
#include "RsmtLiveLinkSource.h"
#include "RsmtProtocol.h"
#include "RsmtReassembler.h"

DEFINE_LOG_CATEGORY_STATIC(LogRsmtLink, Log, All);

namespace
{
std::string ToStd(const FString& S)
{
	const FTCHARToUTF8 Utf8(*S);
	return std::string(Utf8.Get(), Utf8.Length());
}

FString FromStd(const std::string& S)
{
	return FString(UTF8_TO_TCHAR(S.c_str()));
}

FString StreamUrl(const FString& Base, bool bBinary)
{
	FString Url = Base;
	Url.RemoveFromEnd(TEXT("/"));
	if (Url.StartsWith(TEXT("https://")))
	{
		Url = TEXT("wss://") + Url.RightChop(8);
	}
	else if (Url.StartsWith(TEXT("http://")))
	{
		Url = TEXT("ws://") + Url.RightChop(7);
	}
	return Url + TEXT("/v1/stream?encoding=") + (bBinary ? TEXT("binary") : TEXT("json"));
}
}  // namespace

URsmtLinkComponent::URsmtLinkComponent()
{
	PrimaryComponentTick.bCanEverTick = true;
	PrimaryComponentTick.TickGroup = TG_PrePhysics;  // before the animation update reads Live Link
}

void URsmtLinkComponent::BeginPlay()
{
	Super::BeginPlay();
	Connect();
}

void URsmtLinkComponent::EndPlay(const EEndPlayReason::Type EndPlayReason)
{
	Disconnect();
	Super::EndPlay(EndPlayReason);
}

bool URsmtLinkComponent::IsConnected() const
{
	return Socket.IsValid() && Socket->IsConnected();
}

void URsmtLinkComponent::Connect()
{
	Disconnect();
	Session = rsmt::Session();
	Assembler.Reset();
	Buffer = rsmt::JitterBuffer(BufferDelaySeconds);
	Failover = rsmt::Failover();
	bResumeOnHello = false;
	ReconnectAttempt = 0;

	IModularFeatures& Features = IModularFeatures::Get();
	if (Features.IsModularFeatureAvailable(ILiveLinkClient::ModularFeatureName))
	{
		ILiveLinkClient& LiveLink = Features.GetModularFeature<ILiveLinkClient>(ILiveLinkClient::ModularFeatureName);
		Source = MakeShared<FRsmtLiveLinkSource>(ServerUrl);
		LiveLink.AddSource(Source);
	}
	else
	{
		UE_LOG(LogRsmtLink, Warning, TEXT("Live Link is not available: enable the Live Link plugin"));
	}
	OpenSocket();
}

void URsmtLinkComponent::OpenSocket()
{
	FWebSocketsModule& WebSockets = FModuleManager::LoadModuleChecked<FWebSocketsModule>(TEXT("WebSockets"));
	TMap<FString, FString> Headers;
	if (!ApiKey.IsEmpty())
	{
		Headers.Add(TEXT("X-API-Key"), ApiKey);
	}
	Socket = WebSockets.CreateWebSocket(StreamUrl(ServerUrl, bBinaryFrames), TEXT(""), Headers);
	Socket->OnConnected().AddUObject(this, &URsmtLinkComponent::HandleConnected);
	Socket->OnConnectionError().AddUObject(this, &URsmtLinkComponent::HandleConnectionError);
	Socket->OnClosed().AddUObject(this, &URsmtLinkComponent::HandleClosed);
	// Only OnRawMessage is bound: it carries every message (text and binary) in arrival order, in pieces
	// with BytesRemaining; RsmtCore reassembles and classifies them. (Binding OnMessage as well would
	// deliver text twice on some platforms.)
	Socket->OnRawMessage().AddUObject(this, &URsmtLinkComponent::HandleRawMessage);
	Socket->Connect();
}

void URsmtLinkComponent::Disconnect()
{
	if (GetWorld() != nullptr)
	{
		GetWorld()->GetTimerManager().ClearTimer(ReconnectTimer);
	}
	bResumeOnHello = false;
	CloseSocket();
	if (Source.IsValid() && IModularFeatures::Get().IsModularFeatureAvailable(ILiveLinkClient::ModularFeatureName))
	{
		IModularFeatures::Get().GetModularFeature<ILiveLinkClient>(ILiveLinkClient::ModularFeatureName).RemoveSource(Source);
	}
	Source.Reset();
}

void URsmtLinkComponent::CloseSocket()
{
	if (Socket.IsValid())
	{
		Socket->OnConnected().RemoveAll(this);
		Socket->OnConnectionError().RemoveAll(this);
		Socket->OnClosed().RemoveAll(this);
		Socket->OnRawMessage().RemoveAll(this);
		if (Socket->IsConnected())
		{
			Socket->Close(1000, TEXT("bye"));
		}
		Socket.Reset();
	}
}

// Failover: after a lost connection (or a failed reconnection), wait and open a new socket to the same URL; the
// new hello resumes the character (HandleMessage). The Live Link source and the jitter buffer stay.
void URsmtLinkComponent::ScheduleReconnect(const FString& Why)
{
	if (ReconnectAttempt >= ReconnectAttempts || GetWorld() == nullptr)
	{
		bResumeOnHello = false;
		OnError.Broadcast(TEXT("closed"), Why + FString::Printf(TEXT(" (gave up after %d reconnection attempts)"), ReconnectAttempt));
		return;
	}
	bResumeOnHello = true;
	const float Delay = static_cast<float>(rsmt::Failover::ReconnectDelay(ReconnectAttempt++));
	UE_LOG(LogRsmtLink, Log, TEXT("connection lost (%s): reconnecting in %.2f s"), *Why, Delay);
	GetWorld()->GetTimerManager().SetTimer(ReconnectTimer, FTimerDelegate::CreateWeakLambda(this, [this]()
		{
			CloseSocket();
			Session = rsmt::Session();  // the new connection begins with its own hello
			Assembler.Reset();
			OpenSocket();
		}), FMath::Max(Delay, 0.01f), false);
}

void URsmtLinkComponent::HandleConnected()
{
	UE_LOG(LogRsmtLink, Log, TEXT("connected to %s"), *ServerUrl);
}

void URsmtLinkComponent::HandleConnectionError(const FString& Error)
{
	// A refused handshake (429, 503, a replica still starting) while failing over: try again.
	if (bFailover && (bResumeOnHello || Failover.Live()))
	{
		ScheduleReconnect(Error);
		return;
	}
	OnError.Broadcast(TEXT("connection"), Error);
}

void URsmtLinkComponent::HandleClosed(int32 StatusCode, const FString& Reason, bool bWasClean)
{
	// 1000: idle, 1001: server shutting down (reconnect), 1008: not reading fast enough, 1009: message too big.
	if (bFailover && rsmt::Failover::Resumable(StatusCode) && (bResumeOnHello || Failover.Live()))
	{
		if (!bResumeOnHello)
		{
			ReconnectAttempt = 0;  // a new loss: a fresh series of attempts
		}
		ScheduleReconnect(FString::Printf(TEXT("%d %s"), StatusCode, *Reason));
		return;
	}
	OnError.Broadcast(TEXT("closed"), FString::Printf(TEXT("%d %s"), StatusCode, *Reason));
}

void URsmtLinkComponent::HandleRawMessage(const void* Data, SIZE_T Size, SIZE_T BytesRemaining)
{
	using FResult = rsmt::MessageAssembler::Result;
	const FResult Result = Assembler.Feed(Data, static_cast<std::size_t>(Size), static_cast<std::size_t>(BytesRemaining));
	if (Result == FResult::Partial)
	{
		return;
	}
	if (Result == FResult::TooLarge)
	{
		OnError.Broadcast(TEXT("protocol"), TEXT("a message over 1 MiB was dropped"));
		return;
	}
	const std::vector<uint8>& Bytes = Assembler.Data();
	rsmt::Message Message;
	std::string Error;
	const bool bText = rsmt::ClassifyMessage(Bytes.data(), Bytes.size()) == rsmt::PayloadKind::Text;
	const bool bOk = bText ? Session.HandleText(reinterpret_cast<const char*>(Bytes.data()), Bytes.size(), Message, &Error)
	                       : Session.HandleBinary(Bytes.data(), Bytes.size(), Message, &Error);
	if (!bOk)
	{
		UE_LOG(LogRsmtLink, Warning, TEXT("bad message: %s"), *FromStd(Error));
		return;
	}
	HandleMessage(Message);
}

void URsmtLinkComponent::HandleMessage(rsmt::Message& Message)
{
	if (bFailover && Message.kind != rsmt::MessageKind::Hello)
	{
		// Renumbers a resumed character's frames (model axes, before conversion); answers unknown_style.
		const rsmt::FailoverAction Action = Failover.Received(Message);
		if (!Action.deliver)
		{
			if (Action.registerStyleBody.empty())
				SendText(Action.resend);  // a resume sent again as it was refused
			else
				PostStyle(Action.registerStyleBody, 0, Action.resend);
			return;
		}
	}
	switch (Message.kind)
	{
	case rsmt::MessageKind::Hello:
	{
		const rsmt::ModelInfo& Model = Session.GetHello().model;
		std::string Why;
		if (!rsmt::CheckModelConventions(Model, &Why))
		{
			OnError.Broadcast(TEXT("protocol"), FromStd(Why));
			return;
		}
		CmPerUnit = rsmt::CentimetresPerUnit(Model.units);
		Buffer.SetFps(Model.fps);
		Cuts = rsmt::MotionCutter(rsmt::LimitsOf(Model));
		Cuts.SetNotice([](const std::string& Note) { UE_LOG(LogRsmtLink, Warning, TEXT("%s"), *FromStd(Note)); });
		TArray<FName> Names;
		TArray<int32> Parents;
		RestTransforms.Reset();
		const std::vector<rsmt::Vec3> Offsets = rsmt::UnrealRestOffsets(Model);
		for (size_t J = 0; J < Model.joints.size(); ++J)
		{
			Names.Add(FName(*FromStd(Model.joints[J].name)));
			Parents.Add(Model.joints[J].parent);
			RestTransforms.Add(FTransform(FQuat::Identity, FVector(Offsets[J].x, Offsets[J].y, Offsets[J].z)));
		}
		if (Source.IsValid())
		{
			Source->PushSkeleton(SubjectName, Names, Parents);
		}
		OnConnected.Broadcast();
		if (bResumeOnHello)
		{
			bResumeOnHello = false;
			ReconnectAttempt = 0;
			PendingStart.clear();  // the resume state holds it
			for (const std::string& Text : Failover.ResumeMessages())
			{
				SendText(Text);
			}
		}
		else if (!PendingStart.empty())
		{
			SendText(PendingStart);
			PendingStart.clear();
		}
		if (PendingBvhStart)
		{
			TFunction<void()> Start = MoveTemp(PendingBvhStart);
			PendingBvhStart = nullptr;
			Start();
		}
		break;
	}
	case rsmt::MessageKind::Started:
		if (Message.character == ToStd(CharacterId) && !Message.resumed)  // a resumed character plays on
		{
			Buffer.Reset();
		}
		break;
	case rsmt::MessageKind::Frame:
		if (Message.frame.character == ToStd(CharacterId))
		{
			rsmt::Frame Converted = Message.frame;
			Converted.pose = rsmt::ModelToUnrealPose(Message.frame.pose, CmPerUnit);
			Buffer.Push(Converted, FPlatformTime::Seconds());
		}
		break;
	case rsmt::MessageKind::End:
		if (Message.character == ToStd(CharacterId))
		{
			Buffer.MarkEnded();
			OnTransitionEnded.Broadcast(FromStd(Message.reason), Message.frames);
		}
		break;
	case rsmt::MessageKind::Error:
		OnError.Broadcast(FromStd(Message.code), FromStd(Message.message) +
			(bFailover && Message.code == "unknown_style" ? TEXT(" (no clip held to register it again: use RegisterStyle)") : TEXT("")));
		break;
	default:
		break;
	}
}

void URsmtLinkComponent::TickComponent(float DeltaTime, ELevelTick TickType, FActorComponentTickFunction* ThisTickFunction)
{
	Super::TickComponent(DeltaTime, TickType, ThisTickFunction);
	if (!Source.IsValid() || RestTransforms.Num() == 0)
	{
		return;
	}
	rsmt::Pose Pose;
	if (!Buffer.Sample(FPlatformTime::Seconds(), Pose) || Pose.rotations.size() != static_cast<size_t>(RestTransforms.Num()))
	{
		return;
	}
	TArray<FTransform> Transforms = RestTransforms;
	for (int32 J = 0; J < Transforms.Num(); ++J)
	{
		const rsmt::Quat& Q = Pose.rotations[static_cast<size_t>(J)];
		Transforms[J].SetRotation(FQuat(Q.x, Q.y, Q.z, Q.w));
	}
	Transforms[0].SetTranslation(FVector(Pose.root.x, Pose.root.y, Pose.root.z));
	Source->PushPose(SubjectName, Transforms);
}

void URsmtLinkComponent::SendText(const std::string& Text)
{
	if (Socket.IsValid() && Socket->IsConnected())
	{
		Socket->Send(FromStd(Text));
	}
}

void URsmtLinkComponent::StartTransition(const FString& ContextBvh, const FString& TargetBvh, int32 Frames, int32 Seed,
	bool bDeterministic)
{
	if (!Session.HasHello() && !bResumeOnHello)
	{
		// The model's limits come with hello: cut and send the motions then.
		PendingBvhStart = [this, ContextBvh, TargetBvh, Frames, Seed, bDeterministic]()
		{
			StartTransition(ContextBvh, TargetBvh, Frames, Seed, bDeterministic);
		};
		return;
	}
	StartTransitionMotion(FromStd(rsmt::BvhMotionJson(Cuts.Context(ToStd(ContextBvh)))),
		FromStd(rsmt::BvhMotionJson(Cuts.Target(ToStd(TargetBvh)))), Frames, Seed, bDeterministic);
}

FString URsmtLinkComponent::BvhMotion(const FString& BvhText)
{
	return FromStd(rsmt::BvhMotionJson(ToStd(BvhText)));
}

void URsmtLinkComponent::RetargetMotion(const FString& TargetMotionJson, int32 Frames)
{
	if (bFailover)
	{
		Failover.SentRetarget(ToStd(CharacterId), ToStd(TargetMotionJson), Frames);
	}
	SendText(rsmt::BuildRetarget(ToStd(CharacterId), ToStd(TargetMotionJson), Frames));
}

void URsmtLinkComponent::StartTransitionMotion(const FString& ContextMotionJson, const FString& TargetMotionJson, int32 Frames,
	int32 Seed, bool bDeterministic)
{
	rsmt::StartOptions Options;
	Options.character = ToStd(CharacterId);
	Options.contextJson = ToStd(ContextMotionJson);
	Options.targetJson = ToStd(TargetMotionJson);
	Options.frames = Frames;
	Options.styleId = ToStd(StyleId);
	Options.hasSeed = Seed >= 0;
	Options.seed = static_cast<uint64>(FMath::Max(Seed, 0));
	Options.deterministic = bDeterministic;
	Options.hasStyleStrength = StyleStrength >= 0.0f;
	Options.styleStrength = StyleStrength;
	const std::string Text = rsmt::BuildStart(Options);
	if (bFailover)
	{
		Failover.SentStart(Options);
	}
	if (bResumeOnHello)
	{
		return;  // reconnecting: the resume sends it
	}
	if (Session.HasHello())
	{
		SendText(Text);
	}
	else
	{
		PendingStart = Text;  // sent when hello arrives
	}
}

void URsmtLinkComponent::Retarget(const FString& TargetBvh, int32 Frames)
{
	RetargetMotion(TargetBvh.IsEmpty() ? FString() : FromStd(rsmt::BvhMotionJson(Cuts.Target(ToStd(TargetBvh)))), Frames);
}

void URsmtLinkComponent::Cancel()
{
	if (bFailover)
	{
		Failover.SentCancel(ToStd(CharacterId));
	}
	SendText(rsmt::BuildCancel(ToStd(CharacterId)));
}

void URsmtLinkComponent::RegisterStyle(const FString& StyleBvh, const FString& Name)
{
	PostStyle("{\"name\":" + rsmt::JsonQuote(ToStd(Name)) + ",\"motion\":" + rsmt::BvhMotionJson(Cuts.Style(ToStd(StyleBvh))) + "}", 0);
}

void URsmtLinkComponent::RegisterStyleClips(const TArray<FString>& StyleBvhs, const FString& Name)
{
	std::vector<std::string> Motions;
	for (const FString& Bvh : StyleBvhs)
	{
		Motions.push_back(rsmt::BvhMotionJson(Cuts.Style(ToStd(Bvh))));
	}
	const std::string Body = rsmt::BuildStyleRegistration(ToStd(Name), Motions);
	if (Body.empty())
	{
		OnError.Broadcast(TEXT("validation_error"), FString::Printf(TEXT("a style is registered from 1 to %d clips; got %d"),
			static_cast<int32>(rsmt::kMaxStyleClips), StyleBvhs.Num()));
		return;
	}
	PostStyle(Body, 0);
}

// POST /v1/styles; Then (a re-registration after unknown_style) is sent once the style is registered.
void URsmtLinkComponent::PostStyle(const std::string& Body, int32 Attempt, const std::string& Then)
{
	TSharedRef<IHttpRequest, ESPMode::ThreadSafe> Request = FHttpModule::Get().CreateRequest();
	FString Base = ServerUrl;
	Base.RemoveFromEnd(TEXT("/"));
	Request->SetURL(Base + TEXT("/v1/styles"));
	Request->SetVerb(TEXT("POST"));
	Request->SetHeader(TEXT("Content-Type"), TEXT("application/json"));
	if (!ApiKey.IsEmpty())
	{
		Request->SetHeader(TEXT("X-API-Key"), ApiKey);
	}
	Request->SetContentAsString(FromStd(Body));
	TWeakObjectPtr<URsmtLinkComponent> WeakThis(this);
	Request->OnProcessRequestComplete().BindLambda(
		[WeakThis, Body, Attempt, Then](FHttpRequestPtr, FHttpResponsePtr Response, bool bConnected)
		{
			URsmtLinkComponent* This = WeakThis.Get();
			if (This == nullptr)
			{
				return;
			}
			const int32 Status = (bConnected && Response.IsValid()) ? Response->GetResponseCode() : 0;
			if ((Status == 429 || Status == 503) && Attempt < 4 && This->GetWorld() != nullptr)
			{
				// Honour Retry-After (seconds), else back off 0.5, 1, 2, 4 s.
				float Wait = 0.5f * static_cast<float>(1 << Attempt);
				const FString After = Response->GetHeader(TEXT("Retry-After"));
				if (!After.IsEmpty() && After.IsNumeric())
				{
					Wait = FCString::Atof(*After);
				}
				FTimerHandle Handle;
				This->GetWorld()->GetTimerManager().SetTimer(Handle,
					FTimerDelegate::CreateWeakLambda(This, [This, Body, Attempt, Then]() { This->PostStyle(Body, Attempt + 1, Then); }),
					FMath::Max(Wait, 0.01f), false);
				return;
			}
			rsmt::JsonValue Json;
			const std::string Text = Response.IsValid() ? ToStd(Response->GetContentAsString()) : std::string();
			if (Status != 201 && Status != 200)
			{
				if (!Then.empty())
				{
					This->Failover.Forget(ToStd(This->CharacterId));  // its style cannot be registered again: not resumable
				}
				const bool bParsed = rsmt::ParseJson(Text, Json, nullptr) && Json.Find("error") != nullptr;
				This->OnError.Broadcast(bParsed ? FromStd(Json.Find("error")->StringOr("code", "http_error")) : TEXT("http_error"),
					bParsed ? FromStd(Json.Find("error")->StringOr("message", "")) : FString::Printf(TEXT("HTTP %d"), Status));
				return;
			}
			if (rsmt::ParseJson(Text, Json, nullptr))
			{
				This->Failover.RememberStyle(Json.StringOr("style_id", ""), Body);
				if (!Then.empty())
				{
					This->SendText(Then);  // the start or style message that named it, once more
					return;
				}
				This->StyleId = FromStd(Json.StringOr("style_id", ""));
				This->OnStyleRegistered.Broadcast(This->StyleId);
			}
		});
	Request->ProcessRequest();
}
