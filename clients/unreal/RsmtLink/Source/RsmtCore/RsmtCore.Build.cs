// RsmtCore: the protocol, conversion, reassembly and jitter-buffer core of RsmtLink, in plain C++17
// (no Unreal types outside RsmtCoreModule.cpp), so it also builds and is tested with g++.
using UnrealBuildTool;

public class RsmtCore : ModuleRules
{
	public RsmtCore(ReadOnlyTargetRules Target) : base(Target)
	{
		PCHUsage = PCHUsageMode.NoPCHs;
		bEnableExceptions = false;
		bUseRTTI = false;
		PublicDependencyModuleNames.Add("Core");
	}
}
