/* The FMI 3.0 functions events.c does not implement, each failing with fmi3Error (3): fmpy binds every function of
 * the standard when it loads a binary.  Defined without the standard's header, with no parameters: a caller's
 * arguments are ignored (the C calling convention lets it), and none of these is called by a co-simulation master
 * that uses only what the modelDescription declares. */
int fmi3_stub_status(void);
int fmi3_stub_status(void) { return 3; }

const char *fmi3GetVersion(void);
const char *fmi3GetVersion(void) { return "3.0"; }

int fmi3ActivateModelPartition(void);
int fmi3ActivateModelPartition(void) { return fmi3_stub_status(); }
int fmi3CompletedIntegratorStep(void);
int fmi3CompletedIntegratorStep(void) { return fmi3_stub_status(); }
int fmi3DeserializeFMUState(void);
int fmi3DeserializeFMUState(void) { return fmi3_stub_status(); }
int fmi3EnterConfigurationMode(void);
int fmi3EnterConfigurationMode(void) { return fmi3_stub_status(); }
int fmi3EnterContinuousTimeMode(void);
int fmi3EnterContinuousTimeMode(void) { return fmi3_stub_status(); }
int fmi3EvaluateDiscreteStates(void);
int fmi3EvaluateDiscreteStates(void) { return fmi3_stub_status(); }
int fmi3ExitConfigurationMode(void);
int fmi3ExitConfigurationMode(void) { return fmi3_stub_status(); }
int fmi3FreeFMUState(void);
int fmi3FreeFMUState(void) { return fmi3_stub_status(); }
int fmi3GetAdjointDerivative(void);
int fmi3GetAdjointDerivative(void) { return fmi3_stub_status(); }
int fmi3GetBinary(void);
int fmi3GetBinary(void) { return fmi3_stub_status(); }
int fmi3GetBoolean(void);
int fmi3GetBoolean(void) { return fmi3_stub_status(); }
int fmi3GetContinuousStateDerivatives(void);
int fmi3GetContinuousStateDerivatives(void) { return fmi3_stub_status(); }
int fmi3GetContinuousStates(void);
int fmi3GetContinuousStates(void) { return fmi3_stub_status(); }
int fmi3GetDirectionalDerivative(void);
int fmi3GetDirectionalDerivative(void) { return fmi3_stub_status(); }
int fmi3GetEventIndicators(void);
int fmi3GetEventIndicators(void) { return fmi3_stub_status(); }
int fmi3GetFMUState(void);
int fmi3GetFMUState(void) { return fmi3_stub_status(); }
int fmi3GetFloat32(void);
int fmi3GetFloat32(void) { return fmi3_stub_status(); }
int fmi3GetInt16(void);
int fmi3GetInt16(void) { return fmi3_stub_status(); }
int fmi3GetInt64(void);
int fmi3GetInt64(void) { return fmi3_stub_status(); }
int fmi3GetInt8(void);
int fmi3GetInt8(void) { return fmi3_stub_status(); }
int fmi3GetIntervalDecimal(void);
int fmi3GetIntervalDecimal(void) { return fmi3_stub_status(); }
int fmi3GetIntervalFraction(void);
int fmi3GetIntervalFraction(void) { return fmi3_stub_status(); }
int fmi3GetNominalsOfContinuousStates(void);
int fmi3GetNominalsOfContinuousStates(void) { return fmi3_stub_status(); }
int fmi3GetNumberOfContinuousStates(void);
int fmi3GetNumberOfContinuousStates(void) { return fmi3_stub_status(); }
int fmi3GetNumberOfEventIndicators(void);
int fmi3GetNumberOfEventIndicators(void) { return fmi3_stub_status(); }
int fmi3GetNumberOfVariableDependencies(void);
int fmi3GetNumberOfVariableDependencies(void) { return fmi3_stub_status(); }
int fmi3GetOutputDerivatives(void);
int fmi3GetOutputDerivatives(void) { return fmi3_stub_status(); }
int fmi3GetShiftDecimal(void);
int fmi3GetShiftDecimal(void) { return fmi3_stub_status(); }
int fmi3GetShiftFraction(void);
int fmi3GetShiftFraction(void) { return fmi3_stub_status(); }
int fmi3GetString(void);
int fmi3GetString(void) { return fmi3_stub_status(); }
int fmi3GetUInt16(void);
int fmi3GetUInt16(void) { return fmi3_stub_status(); }
int fmi3GetUInt32(void);
int fmi3GetUInt32(void) { return fmi3_stub_status(); }
int fmi3GetUInt64(void);
int fmi3GetUInt64(void) { return fmi3_stub_status(); }
int fmi3GetUInt8(void);
int fmi3GetUInt8(void) { return fmi3_stub_status(); }
int fmi3GetVariableDependencies(void);
int fmi3GetVariableDependencies(void) { return fmi3_stub_status(); }
int fmi3InstantiateModelExchange(void);
int fmi3InstantiateModelExchange(void) { return fmi3_stub_status(); }
int fmi3InstantiateScheduledExecution(void);
int fmi3InstantiateScheduledExecution(void) { return fmi3_stub_status(); }
int fmi3SerializeFMUState(void);
int fmi3SerializeFMUState(void) { return fmi3_stub_status(); }
int fmi3SerializedFMUStateSize(void);
int fmi3SerializedFMUStateSize(void) { return fmi3_stub_status(); }
int fmi3SetBinary(void);
int fmi3SetBinary(void) { return fmi3_stub_status(); }
int fmi3SetBoolean(void);
int fmi3SetBoolean(void) { return fmi3_stub_status(); }
int fmi3SetContinuousStates(void);
int fmi3SetContinuousStates(void) { return fmi3_stub_status(); }
int fmi3SetDebugLogging(void);
int fmi3SetDebugLogging(void) { return fmi3_stub_status(); }
int fmi3SetFMUState(void);
int fmi3SetFMUState(void) { return fmi3_stub_status(); }
int fmi3SetFloat32(void);
int fmi3SetFloat32(void) { return fmi3_stub_status(); }
int fmi3SetInt16(void);
int fmi3SetInt16(void) { return fmi3_stub_status(); }
int fmi3SetInt32(void);
int fmi3SetInt32(void) { return fmi3_stub_status(); }
int fmi3SetInt64(void);
int fmi3SetInt64(void) { return fmi3_stub_status(); }
int fmi3SetInt8(void);
int fmi3SetInt8(void) { return fmi3_stub_status(); }
int fmi3SetIntervalDecimal(void);
int fmi3SetIntervalDecimal(void) { return fmi3_stub_status(); }
int fmi3SetIntervalFraction(void);
int fmi3SetIntervalFraction(void) { return fmi3_stub_status(); }
int fmi3SetShiftDecimal(void);
int fmi3SetShiftDecimal(void) { return fmi3_stub_status(); }
int fmi3SetShiftFraction(void);
int fmi3SetShiftFraction(void) { return fmi3_stub_status(); }
int fmi3SetString(void);
int fmi3SetString(void) { return fmi3_stub_status(); }
int fmi3SetTime(void);
int fmi3SetTime(void) { return fmi3_stub_status(); }
int fmi3SetUInt16(void);
int fmi3SetUInt16(void) { return fmi3_stub_status(); }
int fmi3SetUInt32(void);
int fmi3SetUInt32(void) { return fmi3_stub_status(); }
int fmi3SetUInt64(void);
int fmi3SetUInt64(void) { return fmi3_stub_status(); }
int fmi3SetUInt8(void);
int fmi3SetUInt8(void) { return fmi3_stub_status(); }
