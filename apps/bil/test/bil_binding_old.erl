%% @doc Internal. Computes the Body Mapping Registry of one pairing: binds
%% every `Consumes' entry to at most one `Service' of an entity of the other
%% type, exactly as docs/bil.md section 4 says. Pure; also exports the
%% keyword normalisation that the rules compare with.
-module(bil_binding_old).

-export([bind/1, keyword/1]).

%% A provider after normalisation: where it lives, and its parameters'
%% value keywords by name keyword.
-record(provider, {endpoint :: bil:endpoint(),
                   params :: #{binary() => [binary()]}}).

-type bucket_key() :: {bil:entity_type(), Category :: binary(), Type :: binary()}.
-type index() :: #{bucket_key() => [#provider{}]}.

%% A consumer's parameters grouped by name keyword, in first-seen order; a
%% name keyword can repeat when names differ only in case or punctuation.
-type wants() :: [{Name :: binary(), Values :: [binary()]}].

-define(YES, <<"yes">>).
-define(NO, <<"no">>).
-define(ANY, <<"any">>).

%% @doc Binds the consumers of the given descriptions, listed in
%% registration order, to the services of the other entity type.
%% Both result lists follow registration order, then document order.
-spec bind([bil:description()]) -> bil:bind_result().
bind(Descriptions) ->
    Index = index(Descriptions),
    {Bound, Unbound} = bind_entities(Descriptions, Index, [], []),
    #{bound => lists:reverse(Bound), unbound => lists:reverse(Unbound)}.

%% @doc The keyword of a category, type, parameter name or parameter value:
%% Unicode case folding (`string:casefold/1'), then every code point that is
%% not a letter (general category L) or a decimal digit (Nd) removed, so
%% `<<"ACTION FEEDBACK">>', `<<"ActionFeedback">>' and
%% `<<"action_feedback">>' all give `<<"actionfeedback">>'. Never raises:
%% input that is not valid UTF-8 (the parsers never produce it) keeps only
%% its ASCII letters and digits.
-spec keyword(binary()) -> binary().
keyword(Bin) when is_binary(Bin) ->
    case ascii_keyword(Bin, []) of
        not_ascii ->
            case unicode:characters_to_binary(Bin) of
                Bin -> unicode_keyword(Bin);
                _Invalid -> ascii_only_keyword(Bin, [])
            end;
        Keyword ->
            Keyword
    end.

%% ---------------------------------------------------------------------------
%% Keywords
%% ---------------------------------------------------------------------------

%% For ASCII, case folding is A-Z to a-z and no other character can fold
%% into a letter or digit, so this matches the Unicode path without regexes.
%% Almost every keyword is ASCII; a list accumulator is the fastest build.
ascii_keyword(<<C, Rest/binary>>, Acc) when C < 128 ->
    ascii_keyword(Rest, ascii_char(C, Acc));
ascii_keyword(<<>>, Acc) ->
    list_to_binary(lists:reverse(Acc));
ascii_keyword(_, _Acc) ->
    not_ascii.

ascii_only_keyword(<<C, Rest/binary>>, Acc) when C >= 128 ->
    ascii_only_keyword(Rest, Acc);
ascii_only_keyword(<<C, Rest/binary>>, Acc) ->
    ascii_only_keyword(Rest, ascii_char(C, Acc));
ascii_only_keyword(<<>>, Acc) ->
    list_to_binary(lists:reverse(Acc)).

ascii_char(C, Acc) when C >= $a, C =< $z; C >= $0, C =< $9 -> [C | Acc];
ascii_char(C, Acc) when C >= $A, C =< $Z -> [C + 32 | Acc];
ascii_char(_, Acc) -> Acc.

%% NFC first, so a letter written with a combining accent and the same
%% letter precomposed give one keyword (the accent would otherwise be
%% dropped as a non-letter).
unicode_keyword(Bin) ->
    Composed = unicode:characters_to_nfc_binary(Bin),
    Folded = unicode:characters_to_binary(string:casefold(Composed)),
    re:replace(Folded, "[^\\p{L}\\p{Nd}]+", "",
               [global, unicode, ucp, {return, binary}]).

%% ---------------------------------------------------------------------------
%% Index of providers
%% ---------------------------------------------------------------------------

%% Folding from the right and prepending leaves each bucket in registration
%% then document order, so ties are decided by keeping the first best
%% candidate met, and no bucket needs reversing afterwards.
-spec index([bil:description()]) -> index().
index(Descriptions) ->
    lists:foldr(fun index_entity/2, #{}, Descriptions).

index_entity(#{entity_id := EntityId, entity_type := EntityType,
               components := Components}, Acc) ->
    lists:foldr(
      fun(#{id := ComponentId, services := Services}, Acc1) ->
              Endpoint = #{entity => EntityId, component => ComponentId},
              lists:foldr(
                fun(Service, Index) ->
                        Key = {EntityType, keyword(maps:get(category, Service)),
                               keyword(maps:get(type, Service))},
                        Provider = #provider{endpoint = Endpoint,
                                             params = provider_params(Service)},
                        maps:update_with(Key, fun(Ps) -> [Provider | Ps] end,
                                         [Provider], Index)
                end, Acc1, Services)
      end, Acc, Components).

-spec provider_params(bil:entry()) -> #{binary() => [binary()]}.
provider_params(#{parameters := Params}) ->
    lists:foldl(fun({Name, Value}, Map) ->
                        V = keyword(Value),
                        maps:update_with(keyword(Name), fun(Vs) -> [V | Vs] end,
                                         [V], Map)
                end, #{}, Params).

%% ---------------------------------------------------------------------------
%% Binding
%% ---------------------------------------------------------------------------

bind_entities([#{entity_id := EntityId, entity_type := EntityType,
                 components := Components} | Rest], Index, Bound, Unbound) ->
    Wanted = {other(EntityType), EntityId},
    {Bound1, Unbound1} =
        lists:foldl(fun(Component, Acc) ->
                            bind_component(Component, Wanted, Index, Acc)
                    end, {Bound, Unbound}, Components),
    bind_entities(Rest, Index, Bound1, Unbound1);
bind_entities([], _Index, Bound, Unbound) ->
    {Bound, Unbound}.

bind_component(#{id := ComponentId, consumes := Consumes},
               {OtherType, EntityId}, Index, Acc) ->
    Consumer = #{entity => EntityId, component => ComponentId},
    lists:foldl(fun(Entry, {Bound, Unbound}) ->
                        case bind_entry(Entry, OtherType, Index) of
                            {bound, Provider, Score, Count} ->
                                {[binding(Consumer, Entry, Provider, Score, Count)
                                  | Bound], Unbound};
                            {unbound, Reason} ->
                                {Bound, [unbound(Consumer, Entry, Reason) | Unbound]}
                        end
                end, Acc, Consumes).

bind_entry(#{category := Category, type := Type} = Entry, OtherType, Index) ->
    case maps:get({OtherType, keyword(Category), keyword(Type)}, Index, []) of
        [] ->
            {unbound, no_provider};
        Candidates ->
            case choose(wants(Entry), Candidates, none, 0) of
                {_, 0} -> {unbound, parameters_mismatch};
                {{Provider, Score}, Count} -> {bound, Provider, Score, Count}
            end
    end.

%% Strictly greater replaces the best so far: the bucket is in tie-break
%% order, so among equal scores the first compatible candidate stays.
choose(Wants, [Candidate | Rest], Best, Count) ->
    case compatible(Wants, Candidate#provider.params) of
        false ->
            choose(Wants, Rest, Best, Count);
        true ->
            Score = score(Wants, Candidate#provider.params),
            Best1 = case Best of
                        {_, BestScore} when BestScore >= Score -> Best;
                        _ -> {Candidate, Score}
                    end,
            choose(Wants, Rest, Best1, Count + 1)
    end;
choose(_Wants, [], Best, Count) ->
    {Best, Count}.

-spec wants(bil:entry()) -> wants().
wants(#{parameters := Params}) ->
    Grouped = lists:foldl(
                fun({Name, Value}, Acc) ->
                        N = keyword(Name),
                        V = keyword(Value),
                        case lists:keyfind(N, 1, Acc) of
                            {N, Vs} -> lists:keyreplace(N, 1, Acc, {N, [V | Vs]});
                            false -> [{N, [V]} | Acc]
                        end
                end, [], Params),
    lists:reverse(Grouped).

compatible(Wants, Offered) ->
    lists:all(fun({Name, Values}) ->
                      Has = maps:get(Name, Offered, []),
                      lists:all(fun(V) -> satisfied(V, Has) end, Values)
              end, Wants).

satisfied(?NO, _Has) -> true;
satisfied(?YES, Has) -> lists:member(?YES, Has);
satisfied(V, Has) -> lists:member(V, Has) orelse lists:member(?ANY, Has).

%% The number of distinct parameter name keywords for which the consumer and
%% the provider have a value keyword in common.
score(Wants, Offered) ->
    length([Name || {Name, Values} <- Wants,
                    shares_value(Values, maps:get(Name, Offered, []))]).

shares_value(Values, Has) ->
    lists:any(fun(V) -> lists:member(V, Has) end, Values).

binding(Consumer, #{category := Category, type := Type}, Provider, Score, Count) ->
    #{consumer => Consumer, provider => Provider#provider.endpoint,
      category => Category, type => Type, score => Score, candidates => Count}.

unbound(Consumer, #{category := Category, type := Type}, Reason) ->
    #{consumer => Consumer, category => Category, type => Type, reason => Reason}.

other(agent) -> avatar;
other(avatar) -> agent.
