%% @doc Public API of BIL, the Body Integration Language.
%%
%% Parses and encodes BIL descriptions (what an entity's components provide
%% and consume) and BIL signals (the SOAP-like envelopes routed by EVATAR),
%% and computes the Body Mapping Registry from the descriptions of one
%% pairing. Input is untrusted: parsers never raise, never create atoms and
%% refuse DTDs, entities, oversize and over-deep documents. The language is
%% specified in docs/bil.md; every other bil_* module of this app is internal
%% (bil_control, the wire's control documents, is app evatar_protocol's).
-module(bil).

-export([parse_description/1, parse_description/2, encode_description/1,
         parse_signal/1, parse_signal/2, encode_signal/1,
         bind/1, explain_unbound/2, format_error/1, namespace/0, signal_contexts/0,
         parse_xml/2, escape_text/1, keyword/1]).

-export_type([description/0, entity_type/0, component/0, entry/0, parameter/0,
              signal/0, signal_context/0, limits/0, error_reason/0, error_code/0,
              endpoint/0, binding/0, unbound/0, bind_result/0, xml_element/0]).

-define(NAMESPACE, <<"urn:evatar:bil:1">>).

%% ---------------------------------------------------------------------------
%% Descriptions
%% ---------------------------------------------------------------------------

-type entity_type() :: agent | avatar.
%% Parameter names and values are kept as the binaries that were sent, in
%% document order: names are never turned into atoms.
-type parameter() :: {Name :: binary(), Value :: binary()}.
%% One `Service' or `Consumes' entry.
-type entry() :: #{category := binary(),
                   type := binary(),
                   parameters := [parameter()]}.
-type component() :: #{id := binary(),
                       services := [entry()],
                       consumes := [entry()]}.
-type description() :: #{entity_id := binary(),
                         api_name := binary(),
                         entity_type := entity_type(),
                         context := binary(),
                         components := [component()]}.

%% ---------------------------------------------------------------------------
%% Signals
%% ---------------------------------------------------------------------------

-type signal_context() :: request            % request awaiting feedback
                        | request_no_feedback
                        | feedback           % final answer to a request
                        | progress           % intermediate answer, request stays open
                        | sensor_data
                        | event
                        | error.
%% `in_reply_to', `seq' and `epoch' are `undefined' when absent from the
%% document. `timestamp' is milliseconds since 1970-01-01T00:00:00Z.
%% `origin' is present, `evatar', only on signals EVATAR made itself (its
%% Timeout and ProviderGone feedback, its error signals): the header's
%% `Origin' element, which an entity never sends.
-type signal() :: #{id := binary(),
                    context := signal_context(),
                    sender := binary(),
                    receiver := binary(),
                    in_reply_to := binary() | undefined,
                    timestamp := non_neg_integer(),
                    seq := non_neg_integer() | undefined,
                    epoch := non_neg_integer() | undefined,
                    origin => evatar,
                    body := entry()}.

%% ---------------------------------------------------------------------------
%% Limits and errors
%% ---------------------------------------------------------------------------

%% Unset keys take the `bil' application's environment, then the built-in
%% defaults: 64 KiB for a signal, 1 MiB for a description, depth 32.
-type limits() :: #{max_size => pos_integer(), max_depth => pos_integer()}.

-type error_code() :: too_large          % over max_size, refused before parsing
                    | not_binary
                    | doctype_refused    % <!DOCTYPE ...>: no DTDs, so no entities
                    | entity_refused     % &name; other than the five predefined
                    | too_deep
                    | truncated          % input ended inside a construct
                    | malformed          % not well-formed XML of BIL's subset
                    | bad_encoding       % not UTF-8, or a forbidden character
                    | wrong_namespace
                    | wrong_root
                    | missing_element
                    | unexpected_element
                    | duplicate_element
                    | bad_value
                    | duplicate_component.
%% `message' says what was wrong in words a person can act on; `line' and
%% `column' (1-based) locate syntax errors, `path' locates structural ones
%% (for example `/description/types/Component[2]/Service[1]/ServiceType').
-type error_reason() :: #{code := error_code(),
                          message := binary(),
                          line => pos_integer(),
                          column => pos_integer(),
                          path => binary()}.

%% ---------------------------------------------------------------------------
%% Binding
%% ---------------------------------------------------------------------------

-type endpoint() :: #{entity := binary(), component := binary()}.
%% One row of the Body Mapping Registry: the consumer's entry (category and
%% type as the consumer wrote them) bound to exactly one provider.
-type binding() :: #{consumer := endpoint(),
                     provider := endpoint(),
                     category := binary(),
                     type := binary(),
                     score := non_neg_integer(),
                     candidates := pos_integer()}.
-type unbound() :: #{consumer := endpoint(),
                     category := binary(),
                     type := binary(),
                     reason := no_provider | parameters_mismatch}.
-type bind_result() :: #{bound := [binding()], unbound := [unbound()]}.

%% One element of a parsed XML document: `{{Namespace, LocalName},
%% Attributes, Children}', children being elements or text.
-type xml_element() :: bil_xml:element().

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc Why an unbound entry (of {@link bind/1}'s result for the same
%% descriptions) bound nothing: each provider of its category and type with
%% the consumer's parameters it does not satisfy (`{Name, Wanted,
%% Offered}'); `[]' when no entity offers that category and type.
-spec explain_unbound(unbound(), [description()]) ->
          [#{provider := endpoint(), failed := [{binary(), binary(), [binary()]}]}].
explain_unbound(Unbound, Descriptions) ->
    bil_binding:explain(Unbound, Descriptions).

%% @doc The XML namespace of BIL documents.
-spec namespace() -> binary().
namespace() -> ?NAMESPACE.

%% @doc Every signal context, in the order docs/bil.md lists them.
-spec signal_contexts() -> [signal_context()].
signal_contexts() ->
    [request, request_no_feedback, feedback, progress, sensor_data, event, error].

%% @equiv parse_description(Bin, #{})
-spec parse_description(binary()) -> {ok, description()} | {error, error_reason()}.
parse_description(Bin) -> parse_description(Bin, #{}).

%% @doc Parses a BIL description document.
-spec parse_description(binary(), limits()) ->
          {ok, description()} | {error, error_reason()}.
parse_description(Bin, Limits) ->
    bil_description:parse(Bin, bil_limits:resolve(description, Limits)).

%% @doc Encodes a description as a BIL document (UTF-8 iodata).
-spec encode_description(description()) -> iodata().
encode_description(Description) -> bil_description:encode(Description).

%% @equiv parse_signal(Bin, #{})
-spec parse_signal(binary()) -> {ok, signal()} | {error, error_reason()}.
parse_signal(Bin) -> parse_signal(Bin, #{}).

%% @doc Parses a BIL signal (an Envelope with a Header and a Body).
-spec parse_signal(binary(), limits()) -> {ok, signal()} | {error, error_reason()}.
parse_signal(Bin, Limits) ->
    bil_signal:parse(Bin, bil_limits:resolve(signal, Limits)).

%% @doc Encodes a signal as a BIL document (UTF-8 iodata).
-spec encode_signal(signal()) -> iodata().
encode_signal(Signal) -> bil_signal:encode(Signal).

%% @doc Computes the Body Mapping Registry of one pairing from the
%% descriptions registered in it, in registration order. Pure; the rules are
%% in docs/bil.md, section "Binding".
-spec bind([description()]) -> bind_result().
bind(Descriptions) -> bil_binding:bind(Descriptions).

%% @doc Parses one UTF-8 XML document with BIL's own parser: no DTDs, no
%% entities, the size limit checked before parsing, the root at depth 1.
%% For documents that are not descriptions or signals but travel with them
%% (the wire protocol's control documents, app evatar_protocol).
-spec parse_xml(binary(), #{max_size := pos_integer(), max_depth := pos_integer()}) ->
          {ok, xml_element()} | {error, error_reason()}.
parse_xml(Bin, Limits) -> bil_xml:parse(Bin, Limits).

%% @doc Escapes text for use as an element's content, as BIL's encoders do
%% (`&', `<', `>', and CR as a character reference).
-spec escape_text(binary()) -> iodata().
escape_text(Bin) -> bil_xml:escape_text(Bin).

%% @doc The keyword that binding compares (docs/bil.md section 4): Unicode
%% case folding, then every code point that is not a letter or a decimal
%% digit removed (`<<"Action Feedback">>' gives `<<"actionfeedback">>').
-spec keyword(binary()) -> binary().
keyword(Bin) -> bil_binding:keyword(Bin).

%% @doc One line a person can read, for logs and error signals.
-spec format_error(error_reason()) -> binary().
format_error(#{code := Code, message := Message} = Reason) ->
    Where = case Reason of
                #{line := L, column := C} ->
                    io_lib:format(" at line ~b, column ~b", [L, C]);
                #{path := P} ->
                    [" at ", P];
                _ ->
                    ""
            end,
    iolist_to_binary([atom_to_binary(Code), Where, ": ", Message]).
