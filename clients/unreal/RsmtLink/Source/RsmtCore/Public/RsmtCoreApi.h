// RsmtCore: the engine-independent part of the RsmtLink plugin (plain C++17, no Unreal types).
// Unreal Build Tool defines RSMTCORE_API for this module (DLL export/import); elsewhere it is empty.
#pragma once

#ifndef RSMTCORE_API
#define RSMTCORE_API
#endif
