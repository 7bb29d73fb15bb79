//! Arrow data types as chunks see them: the leaf shape of a component's list type (what
//! zero-copy reads and memory accounting need), and type comparisons with the hot cases
//! inline (inserts and merges compare types on every row), helped by list types whose
//! item field is the process-wide shared copy.

use std::sync::Arc;

use arrow_array::{Array, ArrowPrimitiveType, ListArray};
use arrow_schema::DataType;

/// Bytes of one item's leaf values in a list type whose items are primitives or
/// fixed-size lists of them (a scalar's 8, a 3D position's 12); `None` for other types.
pub(crate) fn instance_bytes(list_type: &DataType) -> Option<usize> {
    let (leaf_type, fixed_size) = leaf_shape(list_type)?;
    leaf_type
        .primitive_width()?
        .checked_mul(fixed_size.unwrap_or(1))
}

/// The leaf type of a list type whose items are primitives or fixed-size lists of them,
/// and the fixed size (`None` for primitive items). Arrow checks that a list's values have
/// its item type, so this is the type of the values a [`PrimitiveLeaf`] holds.
pub(crate) fn leaf_shape(list_type: &DataType) -> Option<(&DataType, Option<usize>)> {
    let DataType::List(item) = list_type else {
        return None;
    };
    match item.data_type() {
        DataType::FixedSizeList(leaf, size) => {
            Some((leaf.data_type(), Some(usize::try_from(*size).ok()?)))
        }
        primitive => Some((primitive, None)),
    }
}

/// Is `data_type` `T`'s type? `T::DATA_TYPE` is a temporary, and the comparison with it
/// called `DataType`'s drop (14 of the accessor's 121 instructions a call); a constant
/// holds nothing to free, so it is left undropped.
#[inline]
pub(super) fn is_type_of<T: ArrowPrimitiveType>(data_type: &DataType) -> bool {
    *data_type == *std::mem::ManuallyDrop::new(T::DATA_TYPE)
}

/// `a == b`, first by the shortcuts the hot comparisons of layouts take: a list type whose
/// item field is the process-wide shared copy (see [`with_shared_item_field`]) by pointer,
/// and a sequence timeline's `Int64`. `DataType`'s own equality is an out-of-line call of
/// about 25 instructions, made four times a row when one-row chunks are merged.
#[inline]
pub(crate) fn same_data_type(a: &DataType, b: &DataType) -> bool {
    match (a, b) {
        (DataType::List(x), DataType::List(y)) if Arc::ptr_eq(x, y) => true,
        (DataType::Int64, DataType::Int64) => true,
        _ => a == b,
    }
}

/// `a.equals_datatype(b)` (equal but for nested fields' names and nullability), with the
/// common cases inline: a component's element type is checked on every insert, and
/// `equals_datatype` is an out-of-line call of some 44 instructions.
#[inline]
pub(crate) fn equal_element_types(a: &DataType, b: &DataType) -> bool {
    if is_parameterless(a) {
        std::mem::discriminant(a) == std::mem::discriminant(b)
    } else {
        same_data_type(a, b) || a.equals_datatype(b)
    }
}

/// Is `data_type` one of the types a variant alone describes (no unit, size, time zone or
/// field)? Two of them are equal exactly when their variants are.
#[inline]
fn is_parameterless(data_type: &DataType) -> bool {
    use DataType as T;
    matches!(
        data_type,
        T::Null
            | T::Boolean
            | T::Int8
            | T::Int16
            | T::Int32
            | T::Int64
            | T::UInt8
            | T::UInt16
            | T::UInt32
            | T::UInt64
            | T::Float16
            | T::Float32
            | T::Float64
            | T::Utf8
            | T::LargeUtf8
            | T::Utf8View
            | T::Binary
            | T::LargeBinary
            | T::BinaryView
            | T::Date32
            | T::Date64
    )
}

/// `list` with its item field replaced by the process-wide shared copy of an equal field
/// (see [`crate::interner`]): the same data, and a type that compares by pointer.
pub(crate) fn with_shared_item_field(list: &ListArray) -> ListArray {
    let DataType::List(field) = list.data_type() else {
        return list.clone();
    };
    let shared = crate::interner::share_field(field);
    if std::sync::Arc::ptr_eq(&shared, field) {
        return list.clone();
    }
    // The parts come from a valid list and the field is equal, so this does not fail; if
    // it ever did, the list keeps its own field.
    ListArray::try_new(
        shared,
        list.offsets().clone(),
        std::sync::Arc::clone(list.values()),
        list.nulls().cloned(),
    )
    .unwrap_or_else(|_| list.clone())
}
