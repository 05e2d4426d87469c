"""What every stage uses: the checks at mvcjax's edges (errors naming the argument and
the fix), transfers to the device, the module base, the batching helpers and the
programs compiled for an object (`compiled_by`)."""

from ._batching import (
    one_after_another as one_after_another,
    only_batched as only_batched,
    with_batching_rule as with_batching_rule,
)
from ._checks import (
    NOT_FINITE_TARGETS as NOT_FINITE_TARGETS,
    as_array as as_array,
    as_devices as as_devices,
    as_points as as_points,
    check_targets as check_targets,
    check_when_run as check_when_run,
    checked_on_entry as checked_on_entry,
    checked_option as checked_option,
    checks_left_out as checks_left_out,
    finite_when_traced as finite_when_traced,
    is_real_number as is_real_number,
    is_whole_number as is_whole_number,
    kind_of as kind_of,
    refuse_removed as refuse_removed,
    refuse_string as refuse_string,
    refusing_removed as refusing_removed,
    whole_number as whole_number,
)
from ._module import JittableModule as JittableModule
from ._programs import (
    Programs as Programs,
    compiled_by as compiled_by,
    is_traced as is_traced,
    programs_field as programs_field,
)
from ._progress import progress_bar as progress_bar
from ._xla import materialise as materialise, to_device as to_device
