%% @doc Benchmarks for BIL, printed as tables: how bil:bind/1 scales with the
%% size of a pairing (against a naive quadratic reference), and how fast the
%% BIL codec parses and encodes compared with xmerl in the same run.
%% Not part of the product; see bench/README.md for how to run it.
-module(bil_bench).

-export([main/0, main/1]).

%% `binding' and `codec' choose the parts (both by default); `{sizes, Ns}'
%% the binding sizes; `{seconds, S}' the time spent on each codec figure;
%% `quick' is a smoke run with small sizes and short measurements.
-type option() :: binding | codec | quick
                | {sizes, [pos_integer()]} | {seconds, number()}.

-define(NS, "urn:evatar:bil:1").
%% Runs of each binding measurement; the median is shown.
-define(BIND_RUNS, 5).
%% The naive reference is quadratic: it is run only up to this size.
-define(NAIVE_MAX, 1000).
%% Shared-bucket binding: the index makes it linear (it was N² before issue 16).
-define(SHARED_MAX, 100000).
%% Rounds of each codec measurement; the fastest is shown.
-define(ROUNDS, 10).

%% ---------------------------------------------------------------------------
%% Entry points
%% ---------------------------------------------------------------------------

%% @equiv main([binding, codec])
-spec main() -> ok.
main() ->
    main([binding, codec]).

%% @doc Runs the chosen benchmarks in this process and prints their tables.
-spec main([option()]) -> ok.
main(Options) ->
    ok = io:setopts([{encoding, unicode}]),
    Quick = lists:member(quick, Options),
    Parts = case [P || P <- Options, P =:= binding orelse P =:= codec] of
                [] -> [binding, codec];
                Chosen -> Chosen
            end,
    Sizes = proplists:get_value(sizes, Options,
                                case Quick of
                                    true -> [10, 100];
                                    false -> [100, 1000, 10000]
                                end),
    Seconds = proplists:get_value(seconds, Options,
                                  case Quick of
                                      true -> 0.2;
                                      false -> 1.2
                                  end),
    io:format("BIL benchmarks: OTP ~s, ~b schedulers, ~s~n",
              [erlang:system_info(otp_release), erlang:system_info(schedulers_online),
               erlang:system_info(system_architecture)]),
    _ = [binding(Sizes) || lists:member(binding, Parts)],
    _ = [codec(Seconds) || lists:member(codec, Parts)],
    ok.

%% ---------------------------------------------------------------------------
%% a. Binding scale
%% ---------------------------------------------------------------------------

binding(Sizes) ->
    io:format("~n== Binding: bil:bind/1 on an Avatar with N components and a VA with "
              "N emulators (2N consumers) ==~n"
              "   distinct: every (category, type) differs, so each bucket holds one "
              "service~n"
              "   shared:   all share one (category, type); parameters pick the "
              "provider, so each consumer examines N candidates~n"
              "   ms: wall time, median of ~b runs (naive: 3); kred: reductions of one run "
              "(work done, independent of load and caches)~n"
              "   growth = figure / figure at N/10 (linear ~~10x, quadratic ~~100x); "
              "naive/bind = naive ms / bind ms~n~n",
              [?BIND_RUNS]),
    io:format("~-9s ~6s ~10s ~7s ~10s ~7s ~11s ~7s ~11s ~7s ~10s~n",
              ["variant", "N", "bind ms", "growth", "bind kred", "growth",
               "naive ms", "growth", "naive kred", "growth", "naive/bind"]),
    ok = check_against_naive(lists:min(Sizes)),
    lists:foreach(
      fun(Variant) ->
              Max = case Variant of
                        distinct -> lists:max(Sizes);
                        shared -> ?SHARED_MAX
                    end,
              binding_rows(Variant, [N || N <- Sizes, N =< Max], none),
              _ = [io:format("~-9s ~6b ~10s  (skipped: 2N² candidate checks)~n",
                             [Variant, N, "-"])
               || N <- Sizes, N > Max]
      end, [distinct, shared]).

binding_rows(Variant, [N | Rest], Prev) ->
    Ds = pairing(Variant, N),
    Bind = {median_ms(fun() -> bil:bind(Ds) end, ?BIND_RUNS),
            reductions(fun() -> bil:bind(Ds) end)},
    Naive = case N =< ?NAIVE_MAX of
                true -> {median_ms(fun() -> naive_bind(Ds) end, 3),
                         reductions(fun() -> naive_bind(Ds) end)};
                false -> {undefined, undefined}
            end,
    {PrevBind, PrevNaive} = case Prev of
                                {PN, PB, PV} when N =:= PN * 10 -> {PB, PV};
                                _ -> {{undefined, undefined}, {undefined, undefined}}
                            end,
    {BindMs, BindRed} = Bind,
    {NaiveMs, NaiveRed} = Naive,
    io:format("~-9s ~6b ~10s ~7s ~10s ~7s ~11s ~7s ~11s ~7s ~10s~n",
              [Variant, N, ms(BindMs), growth(BindMs, element(1, PrevBind)),
               kred(BindRed), growth(BindRed, element(2, PrevBind)),
               ms(NaiveMs), growth(NaiveMs, element(1, PrevNaive)),
               kred(NaiveRed), growth(NaiveRed, element(2, PrevNaive)),
               ratio(NaiveMs, BindMs)]),
    binding_rows(Variant, Rest, {N, Bind, Naive});
binding_rows(_Variant, [], _) ->
    ok.

%% The reference must agree with bil:bind/1, or the comparison means nothing.
check_against_naive(N) ->
    lists:foreach(fun(Variant) ->
                          Ds = pairing(Variant, N),
                          Result = bil:bind(Ds),
                          Result = naive_bind(Ds),
                          #{unbound := []} = Result
                  end, [distinct, shared]).

growth(A, B) when is_number(A), is_number(B) -> io_lib:format("~.1fx", [A / B]);
growth(_, _) -> "".

ms(undefined) -> "-";
ms(T) -> io_lib:format("~.2f", [T]).

kred(undefined) -> "-";
kred(R) -> integer_to_list(round(R / 1000)).

ratio(undefined, _) -> "-";
ratio(A, B) -> io_lib:format("~.1fx", [A / B]).

%% An Avatar whose N components each offer one actuator service and consume
%% its feedback, and a VA whose N emulators do the converse; the two sides
%% spell categories and types differently so keywords are exercised.
pairing(Variant, N) ->
    Avatar = [begin
                  Tag = tag(Variant, I),
                  #{id => <<"HomeActuator", (integer_to_binary(I))/binary>>,
                    services => [#{category => <<"ACTUATOR">>,
                                   type => <<"TurnOn", Tag/binary>>,
                                   parameters => [{<<"Light">>, <<"yes">>},
                                                  {<<"Unit">>, unit(I)},
                                                  {<<"Email">>, <<"no">>}]}],
                    consumes => [#{category => <<"ACTUATOR">>,
                                   type => <<"ACTION FEEDBACK", Tag/binary>>,
                                   parameters => [{<<"Unit">>, unit(I)}]}]}
              end || I <- lists:seq(1, N)],
    VA = [begin
              Tag = tag(Variant, I),
              #{id => <<"Emulator", (integer_to_binary(I))/binary>>,
                services => [#{category => <<"actuator">>,
                               type => <<"action_feedback", Tag/binary>>,
                               parameters => [{<<"Unit">>, unit(I)}]}],
                consumes => [#{category => <<"Actuator">>,
                               type => <<"turn on", Tag/binary>>,
                               parameters => [{<<"light">>, <<"YES">>},
                                              {<<"unit">>, unit(I)}]}]}
          end || I <- lists:seq(1, N)],
    [#{entity_id => <<"7008">>, api_name => <<"HOME">>, entity_type => avatar,
       context => <<"Bench">>, components => Avatar},
     #{entity_id => <<"va1">>, api_name => <<"HOME">>, entity_type => agent,
       context => <<"Bench">>, components => VA}].

tag(distinct, I) -> <<" ", (integer_to_binary(I))/binary>>;
tag(shared, _I) -> <<>>.

unit(I) -> <<"u", (integer_to_binary(I))/binary>>.

%% The rules of docs/bil.md section 4 as nested loops: every consumer entry
%% against every service of every entity, keywords computed on the spot.
naive_bind(Ds) ->
    Results = [naive_entry(E, C, Entry, Ds)
               || E <- Ds, C <- maps:get(components, E), Entry <- maps:get(consumes, C)],
    #{bound => [B || {bound, B} <- Results], unbound => [U || {unbound, U} <- Results]}.

naive_entry(#{entity_id := EId, entity_type := EType}, #{id := CId},
            #{category := Cat, type := Type, parameters := Wanted}, Ds) ->
    K = fun bil_binding:keyword/1,
    Consumer = #{entity => EId, component => CId},
    Candidates = [{#{entity => PE, component => PC}, Offered}
                  || #{entity_id := PE, entity_type := PT, components := PCs} <- Ds,
                     PT =/= EType,
                     #{id := PC, services := Ss} <- PCs,
                     #{category := SCat, type := SType, parameters := Offered} <- Ss,
                     K(SCat) =:= K(Cat), K(SType) =:= K(Type)],
    Compatible = [{P, naive_score(Wanted, Offered)}
                  || {P, Offered} <- Candidates, naive_compatible(Wanted, Offered)],
    case {Candidates, Compatible} of
        {[], _} ->
            {unbound, #{consumer => Consumer, category => Cat, type => Type,
                        reason => no_provider}};
        {_, []} ->
            {unbound, #{consumer => Consumer, category => Cat, type => Type,
                        reason => parameters_mismatch}};
        _ ->
            Max = lists:max([S || {_, S} <- Compatible]),
            [{Provider, Max} | _] = [PS || {_, S} = PS <- Compatible, S =:= Max],
            {bound, #{consumer => Consumer, provider => Provider, category => Cat,
                      type => Type, score => Max, candidates => length(Compatible)}}
    end.

naive_compatible(Wanted, Offered) ->
    K = fun bil_binding:keyword/1,
    lists:all(fun({N, V}) ->
                      Has = [K(V2) || {N2, V2} <- Offered, K(N2) =:= K(N)],
                      case K(V) of
                          <<"no">> -> true;
                          <<"yes">> -> lists:member(<<"yes">>, Has);
                          VK -> lists:member(VK, Has) orelse lists:member(<<"any">>, Has)
                      end
              end, Wanted).

naive_score(Wanted, Offered) ->
    K = fun bil_binding:keyword/1,
    length(lists:usort([K(N) || {N, V} <- Wanted, {N2, V2} <- Offered,
                                K(N) =:= K(N2), K(V) =:= K(V2)])).

%% Reductions are the VM's count of work done: unlike wall time they do not
%% depend on the machine's load, caches or garbage collection.
reductions(F) ->
    true = erlang:garbage_collect(),
    {reductions, Before} = erlang:process_info(self(), reductions),
    _ = F(),
    {reductions, After} = erlang:process_info(self(), reductions),
    After - Before.

median_ms(F, Runs) ->
    Times = [begin
                 true = erlang:garbage_collect(),
                 {Us, _} = timer:tc(F),
                 Us / 1000
             end || _ <- lists:seq(1, Runs)],
    lists:nth((Runs + 1) div 2, lists:sort(Times)).

%% ---------------------------------------------------------------------------
%% b. Codec against xmerl
%% ---------------------------------------------------------------------------

codec(Seconds) ->
    io:format("~n== Codec: BIL against xmerl, same documents, same process ==~n"
              "   decode: bil:parse_* (validated terms) vs xmerl_sax_parser:stream/2 with a "
              "no-op event fun (no output at all)~n"
              "           and vs xmerl_sax_parser building a simple-form tree~n"
              "   encode: bil:encode_* vs xmerl:export_simple/2 (xmerl_xml) of the "
              "equivalent, prebuilt simple-form tree;~n"
              "           'raw' times the iodata each returns, 'binary' adds the "
              "conversion to one UTF-8 binary~n"
              "   each figure: fastest of ~b interleaved batches, about ~.1f s in all; "
              "speedup = xmerl time / bil time~n",
              [?ROUNDS, float(Seconds)]),
    Missing = [M || M <- [bil_xml, bil_description, bil_signal],
                    code:ensure_loaded(M) =/= {module, M}],
    case Missing of
        [] ->
            Results = [codec_doc(Doc, Seconds) || Doc <- documents()],
            summary(Results);
        _ ->
            io:format("~n   skipped: codec modules not available: ~p~n", [Missing])
    end.

codec_doc({Name, Kind, Bin, Term}, Seconds) ->
    io:format("~n-- ~s (~b bytes) --~n", [Name, byte_size(Bin)]),
    {Parse, Encode} = case Kind of
                          signal -> {fun bil:parse_signal/1, fun bil:encode_signal/1};
                          description -> {fun bil:parse_description/1,
                                          fun bil:encode_description/1}
                      end,
    case {Parse(Bin), Parse(iolist_to_binary(Encode(Term)))} of
        {{ok, Term}, {ok, Term}} ->
            codec_measure(Name, Bin, Term, simple_form(Kind, Term), Parse, Encode,
                          Seconds);
        Unexpected ->
            io:format("   skipped: parsing the document, or the encoded term, did not "
                      "give the term back:~n   ~p~n", [Unexpected]),
            skipped
    end.

codec_measure(Name, Bin, Term, Tree, Parse, Encode, Seconds) ->
    {ok, _, _} = sax_noop(Bin),
    {ok, [_], _} = sax_tree(Bin),
    [Dec, DecNoop, DecTree, Enc, EncX, EncBin, EncXBin] =
        measure([fun() -> Parse(Bin) end,
                 fun() -> sax_noop(Bin) end,
                 fun() -> sax_tree(Bin) end,
                 fun() -> Encode(Term) end,
                 fun() -> xmerl:export_simple([Tree], xmerl_xml) end,
                 fun() -> iolist_to_binary(Encode(Term)) end,
                 fun() -> unicode:characters_to_binary(
                            xmerl:export_simple([Tree], xmerl_xml))
                 end], Seconds),
    io:format("   ~-40s ~12s ~12s ~9s~n", ["", "ops/s", "µs/op", "speedup"]),
    row("decode bil", Dec, undefined),
    row("decode xmerl_sax no-op", DecNoop, Dec),
    row("decode xmerl_sax tree", DecTree, Dec),
    row("encode bil (raw iodata)", Enc, undefined),
    row("encode xmerl export_simple (raw)", EncX, Enc),
    row("encode bil (binary)", EncBin, undefined),
    row("encode xmerl export_simple (binary)", EncXBin, EncBin),
    {Name, DecNoop / Dec, DecTree / Dec, EncX / Enc, EncXBin / EncBin}.

row(Label, Us, Base) ->
    Speedup = case Base of
                  undefined -> "";
                  _ -> io_lib:format("~.1fx", [Us / Base])
              end,
    io:format("   ~-40s ~12b ~12.2f ~9s~n", [Label, round(1.0e6 / Us), Us, Speedup]).

summary(Results) ->
    io:format("~n-- goals: decode >= 5x faster than xmerl (judged against the no-op SAX "
              "pass), encode >= 10x faster than export_simple (raw) --~n"),
    io:format("   ~-28s ~10s ~10s ~10s ~10s  ~s~n",
              ["document", "dec/noop", "dec/tree", "enc/raw", "enc/bin", "goals"]),
    lists:foreach(
      fun({Name, Noop, Tree, Raw, Bin}) ->
              Verdict = [goal("decode", Noop >= 5), ", ", goal("encode", Raw >= 10)],
              io:format("   ~-28s ~9.1fx ~9.1fx ~9.1fx ~9.1fx  ~s~n",
                        [Name, Noop, Tree, Raw, Bin, Verdict]);
         (skipped) ->
              ok
      end, Results).

goal(What, true) -> [What, " met"];
goal(What, false) -> [What, " NOT met"].

%% Microseconds per call of each fun. The funs are measured in turns, one
%% batch each per round, so a burst of other load on the machine hits them
%% all alike; each fun's fastest round is kept, as other load can only add
%% time. Batches are sized so the rounds take about Seconds per fun.
measure(Funs, Seconds) ->
    Sized = [{F, max(1, round(Seconds / ?ROUNDS * 1.0e6 / calibrate(F, 1)))}
             || F <- Funs],
    Rounds = [[batch(F, Iterations) || {F, Iterations} <- Sized]
              || _ <- lists:seq(1, ?ROUNDS)],
    [lists:min(PerFun) || PerFun <- transpose(Rounds)].

batch(F, Iterations) ->
    true = erlang:garbage_collect(),
    {Us, ok} = timer:tc(fun() -> repeat(F, Iterations) end),
    Us / Iterations.

transpose([[] | _]) -> [];
transpose(Rows) -> [[hd(R) || R <- Rows] | transpose([tl(R) || R <- Rows])].

calibrate(F, N) ->
    {Us, ok} = timer:tc(fun() -> repeat(F, N) end),
    case Us >= 50000 of
        true -> Us / N;
        false -> calibrate(F, N * 2)
    end.

repeat(_F, 0) ->
    ok;
repeat(F, N) ->
    _ = F(),
    repeat(F, N - 1).

sax_noop(Bin) ->
    xmerl_sax_parser:stream(Bin, [{event_fun, fun(_Event, _Location, State) -> State end},
                                  {event_state, []}]).

%% Builds {Name, Attributes, Content} with names as strings, the least a
%% SAX user must do to get the document as a tree.
sax_tree(Bin) ->
    xmerl_sax_parser:stream(Bin, [{event_fun, fun tree_event/3}, {event_state, []}]).

tree_event({startElement, _Uri, _Local, {Prefix, Local}, Attributes}, _Location, Stack) ->
    [{qualified(Prefix, Local), [{qualified(P, L), V} || {_, P, L, V} <- Attributes], []}
     | Stack];
tree_event({characters, Text}, _Location, [{Name, Attributes, Content} | Stack]) ->
    [{Name, Attributes, [Text | Content]} | Stack];
tree_event({endElement, _Uri, _Local, _QName}, _Location, [{Name, Attributes, Content} | Stack]) ->
    Element = {Name, Attributes, lists:reverse(Content)},
    case Stack of
        [{PName, PAttributes, PContent} | Rest] -> [{PName, PAttributes, [Element | PContent]} | Rest];
        [] -> [Element]
    end;
tree_event(_Event, _Location, Stack) ->
    Stack.

qualified([], Local) -> Local;
qualified(Prefix, Local) -> Prefix ++ ":" ++ Local.

%% ---------------------------------------------------------------------------
%% Documents, and the same content as xmerl simple form
%% ---------------------------------------------------------------------------

documents() ->
    Request = #{id => <<"va1-000042">>, context => request,
                sender => <<"LightEmulator01">>, receiver => <<"HomeLightActuator01">>,
                in_reply_to => undefined, timestamp => 1763800000000, seq => 42, epoch => 1,
                body => #{category => <<"ACTUATOR">>, type => <<"TurnLightOn">>,
                          parameters => [{<<"Light">>, <<"yes">>},
                                         {<<"Room">>, <<"kitchen">>},
                                         {<<"Brightness">>, <<"80">>}]}},
    Sensor = #{id => <<"av1-7">>, context => sensor_data,
               sender => <<"Thermo1">>, receiver => <<"TempEmu1">>,
               in_reply_to => undefined, timestamp => 1763800000123, seq => undefined,
               epoch => undefined,
               body => #{category => <<"SENSOR">>, type => <<"Temperature">>,
                         parameters => [{<<"Celsius">>, <<"21.5">>}]}},
    Light = #{entity_id => <<"7008">>, api_name => <<"LIGHT ACTUATOR">>,
              entity_type => avatar, context => <<"ActuatorDescription">>,
              components => [#{id => <<"HomeLightActuator01">>,
                               services => [#{category => <<"ACTUATOR">>,
                                              type => <<"TurnLightOn">>,
                                              parameters => [{<<"Light">>, <<"yes">>},
                                                             {<<"Email">>, <<"no">>}]}],
                               consumes => [#{category => <<"ACTUATOR">>,
                                              type => <<"ACTION FEEDBACK">>,
                                              parameters => [{<<"Feedback">>, <<"yes">>}]}]}]},
    [Large | _] = pairing(distinct, 1000),
    [{"request signal, 3 parameters", signal, signal_xml(Request), Request},
     {"sensor-data signal", signal, signal_xml(Sensor), Sensor},
     {"light actuator description", description, description_xml(Light), Light},
     {"avatar, 1000 components", description, description_xml(Large), Large}].

%% The documents are written here, not by bil's encoder, so that decoding is
%% measured on text another implementation could send: signals compact, as
%% on the wire; descriptions indented, as files written by a person.
signal_xml(#{id := Id, context := Context, sender := Sender, receiver := Receiver,
             timestamp := Timestamp, seq := Seq, epoch := Epoch, body := Body}) ->
    iolist_to_binary(
      ["<?xml version=\"1.0\" encoding=\"UTF-8\"?>"
       "<bil:Envelope xmlns:bil=\"" ?NS "\"><bil:Header>",
       field("SignalID", Id, compact), field("Context", context_name(Context), compact),
       field("Sender", Sender, compact), field("Receiver", Receiver, compact),
       field("Timestamp", integer_to_binary(Timestamp), compact),
       [field("Sequence", integer_to_binary(Seq), compact) || Seq =/= undefined],
       [field("Epoch", integer_to_binary(Epoch), compact) || Epoch =/= undefined],
       "</bil:Header><bil:Body>",
       entry_fields(Body, compact),
       "</bil:Body></bil:Envelope>"]).

description_xml(#{entity_id := Id, api_name := Api, entity_type := Type,
                  context := Context, components := Components}) ->
    iolist_to_binary(
      ["<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n"
       "<bil:description xmlns:bil=\"" ?NS "\">\n"
       "  <bil:context>\n",
       field("EntityID", Id, "    "), field("APIName", Api, "    "),
       field("EntityType", case Type of agent -> "Agent"; avatar -> "Avatar" end, "    "),
       field("Context", Context, "    "),
       "  </bil:context>\n"
       "  <bil:types>\n",
       [["    <bil:Component>\n",
         field("ComponentID", CId, "      "),
         [["      <Service>\n", entry_fields(S, "        "), "      </Service>\n"]
          || S <- Services],
         [["      <Consumes>\n", entry_fields(C, "        "), "      </Consumes>\n"]
          || C <- Consumes],
         "    </bil:Component>\n"]
        || #{id := CId, services := Services, consumes := Consumes} <- Components],
       "  </bil:types>\n"
       "</bil:description>\n"]).

field(Name, Value, compact) ->
    ["<", Name, ">", Value, "</", Name, ">"];
field(Name, Value, Indent) ->
    [Indent, "<", Name, ">", Value, "</", Name, ">\n"].

entry_fields(#{category := Category, type := Type, parameters := Parameters}, compact) ->
    [field("ServiceCategory", Category, compact), field("ServiceType", Type, compact),
     "<ServiceParameters>", [field(N, V, compact) || {N, V} <- Parameters],
     "</ServiceParameters>"];
entry_fields(#{category := Category, type := Type, parameters := Parameters}, Indent) ->
    [field("ServiceCategory", Category, Indent), field("ServiceType", Type, Indent),
     Indent, "<ServiceParameters>\n",
     [field(N, V, ["  ", Indent]) || {N, V} <- Parameters],
     Indent, "</ServiceParameters>\n"].

context_name(request) -> "RequestAwaitingFeedback";
context_name(request_no_feedback) -> "Request";
context_name(feedback) -> "Feedback";
context_name(progress) -> "Progress";
context_name(sensor_data) -> "SensorData";
context_name(event) -> "Event";
context_name(error) -> "Error".

%% xmerl's simple form needs atom tags; these come from the benchmark's own
%% documents, never from input.
simple_form(signal, #{id := Id, context := Context, sender := Sender,
                      receiver := Receiver, timestamp := Timestamp, seq := Seq,
                      epoch := Epoch, body := Body}) ->
    {'bil:Envelope', [{'xmlns:bil', ?NS}],
     [{'bil:Header', [],
       [text('SignalID', Id), text('Context', context_name(Context)),
        text('Sender', Sender), text('Receiver', Receiver),
        text('Timestamp', integer_to_list(Timestamp))]
       ++ [text('Sequence', integer_to_list(Seq)) || Seq =/= undefined]
       ++ [text('Epoch', integer_to_list(Epoch)) || Epoch =/= undefined]},
      {'bil:Body', [], simple_entry(Body)}]};
simple_form(description, #{entity_id := Id, api_name := Api, entity_type := Type,
                           context := Context, components := Components}) ->
    {'bil:description', [{'xmlns:bil', ?NS}],
     [{'bil:context', [],
       [text('EntityID', Id), text('APIName', Api),
        text('EntityType', case Type of agent -> "Agent"; avatar -> "Avatar" end),
        text('Context', Context)]},
      {'bil:types', [],
       [{'bil:Component', [],
         [text('ComponentID', CId)]
         ++ [{'Service', [], simple_entry(S)} || S <- Services]
         ++ [{'Consumes', [], simple_entry(C)} || C <- Consumes]}
        || #{id := CId, services := Services, consumes := Consumes} <- Components]}]}.

simple_entry(#{category := Category, type := Type, parameters := Parameters}) ->
    [text('ServiceCategory', Category), text('ServiceType', Type),
     {'ServiceParameters', [], [text(binary_to_atom(N), V) || {N, V} <- Parameters]}].

text(Tag, Value) when is_binary(Value) -> {Tag, [unicode:characters_to_list(Value)]};
text(Tag, Value) -> {Tag, [Value]}.
