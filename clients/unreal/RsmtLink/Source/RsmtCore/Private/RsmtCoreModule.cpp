// The Unreal module entry point of RsmtCore: the only file of this module that sees Unreal.
// (The g++ tests compile every other file of Private/ without Unreal.)
#include "Modules/ModuleManager.h"

IMPLEMENT_MODULE(FDefaultModuleImpl, RsmtCore)
