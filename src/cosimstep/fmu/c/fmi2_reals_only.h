/* The Integer, Boolean and String accessors of an FMI 2.0 FMU that has Real variables only:
 * each accepts an empty request and refuses any other with an error the importer can read.
 *
 * Include after defining REALS_ONLY_FAIL(c, message), which logs ``message`` for component c
 * and evaluates to fmi2Error (the frames' own error reporting).
 */
#ifndef COSIMSTEP_FMI2_REALS_ONLY_H
#define COSIMSTEP_FMI2_REALS_ONLY_H

#define REALS_ONLY_REFUSE(fname, type)                                                        \
    do {                                                                                      \
        (void)vr;                                                                             \
        (void)value;                                                                          \
        if (nvr) return REALS_ONLY_FAIL(c, fname ": this FMU has no " type " variables");     \
        return fmi2OK;                                                                        \
    } while (0)

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    REALS_ONLY_REFUSE("fmi2GetInteger", "Integer");
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    REALS_ONLY_REFUSE("fmi2GetBoolean", "Boolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    REALS_ONLY_REFUSE("fmi2GetString", "String");
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    REALS_ONLY_REFUSE("fmi2SetInteger", "Integer");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    REALS_ONLY_REFUSE("fmi2SetBoolean", "Boolean");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    REALS_ONLY_REFUSE("fmi2SetString", "String");
}

#endif /* COSIMSTEP_FMI2_REALS_ONLY_H */
