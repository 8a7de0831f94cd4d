using UnrealBuildTool;

public class RsmtLink : ModuleRules
{
	public RsmtLink(ReadOnlyTargetRules Target) : base(Target)
	{
		PCHUsage = PCHUsageMode.UseExplicitOrSharedPCHs;
		// RsmtCore: protocol, conversion, reassembly and jitter buffer (plain C++; its headers appear in ours).
		PublicDependencyModuleNames.AddRange(new string[] { "Core", "CoreUObject", "Engine", "LiveLinkInterface", "RsmtCore" });
		// WebSockets: IWebSocket for /v1/stream. HTTP: POST /v1/styles.
		PrivateDependencyModuleNames.AddRange(new string[] { "WebSockets", "HTTP" });
	}
}
