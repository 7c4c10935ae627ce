/*
 * fmi3_stubs.h -- FMI 3.0 functions that both FMI 3 wrappers (fmi3_cs.c, fmi3_me.c) answer the
 * same way: getters/setters of the types these FMUs have no variables of (an error naming the
 * value references), and per-element variable dependencies (not provided).
 *
 * Included once, inside a wrapper, after it has defined INSTANCE, GET_MODES, SET_MODES,
 * MODE_ANY (cs_core.h) and not_supported().
 */
#ifndef LPVPC_FMI3_STUBS_H
#define LPVPC_FMI3_STUBS_H

/* the types this FMU has no variables of */
#define GETTER(T, CT)                                                                                    \
    FMI3_Export fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                                      size_t nValueReferences, CT values[], size_t nValues)              \
    {                                                                                                    \
        (void)values;                                                                                    \
        (void)nValues;                                                                                   \
        return (fmi3Status)cs_no_such_type(INSTANCE(instance), "fmi3Get" #T, GET_MODES, valueReferences,  \
                                           nValueReferences);                                            \
    }
#define SETTER(T, CT)                                                                                    \
    FMI3_Export fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[], \
                                      size_t nValueReferences, const CT values[], size_t nValues)        \
    {                                                                                                    \
        (void)values;                                                                                    \
        (void)nValues;                                                                                   \
        return (fmi3Status)cs_no_such_type(INSTANCE(instance), "fmi3Set" #T, SET_MODES, valueReferences,  \
                                           nValueReferences);                                            \
    }

GETTER(Float32, fmi3Float32)
GETTER(Int8, fmi3Int8)
GETTER(UInt8, fmi3UInt8)
GETTER(Int16, fmi3Int16)
GETTER(UInt16, fmi3UInt16)
GETTER(Int32, fmi3Int32)
GETTER(UInt32, fmi3UInt32)
GETTER(Int64, fmi3Int64)
GETTER(UInt64, fmi3UInt64)
GETTER(Boolean, fmi3Boolean)
GETTER(String, fmi3String)
SETTER(Float32, fmi3Float32)
SETTER(Int8, fmi3Int8)
SETTER(UInt8, fmi3UInt8)
SETTER(Int16, fmi3Int16)
SETTER(UInt16, fmi3UInt16)
SETTER(Int32, fmi3Int32)
SETTER(UInt32, fmi3UInt32)
SETTER(Int64, fmi3Int64)
SETTER(UInt64, fmi3UInt64)
SETTER(Boolean, fmi3Boolean)
SETTER(String, fmi3String)

FMI3_Export fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                     size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                                     size_t nValues)
{
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return (fmi3Status)cs_no_such_type(INSTANCE(instance), "fmi3GetBinary", GET_MODES, valueReferences,
                                       nValueReferences);
}

FMI3_Export fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                     size_t nValueReferences, const size_t valueSizes[], const fmi3Binary values[],
                                     size_t nValues)
{
    (void)valueSizes;
    (void)values;
    (void)nValues;
    return (fmi3Status)cs_no_such_type(INSTANCE(instance), "fmi3SetBinary", SET_MODES, valueReferences,
                                       nValueReferences);
}

FMI3_Export fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, fmi3Clock values[])
{
    (void)values;
    return (fmi3Status)cs_no_such_type(INSTANCE(instance), "fmi3GetClock", MODE_ANY, valueReferences,
                                       nValueReferences);
}

FMI3_Export fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Clock values[])
{
    (void)values;
    return (fmi3Status)cs_no_such_type(INSTANCE(instance), "fmi3SetClock", MODE_ANY, valueReferences,
                                       nValueReferences);
}

/* ---------------------------------------------------- variable dependencies */

FMI3_Export fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                                           size_t *nDependencies)
{
    (void)valueReference;
    (void)nDependencies;
    return not_supported(instance, "fmi3GetNumberOfVariableDependencies", "providesPerElementDependencies=false");
}

FMI3_Export fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                                   size_t elementIndicesOfDependent[],
                                                   fmi3ValueReference independents[],
                                                   size_t elementIndicesOfIndependents[],
                                                   fmi3DependencyKind dependencyKinds[], size_t nDependencies)
{
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    return not_supported(instance, "fmi3GetVariableDependencies", "providesPerElementDependencies=false");
}


#endif /* LPVPC_FMI3_STUBS_H */
